-- =================================================================================================
-- Title    : canopen_master_core
-- Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
-- SPDX-License-Identifier: Apache-2.0
-- =================================================================================================
-- Module:
--   The CANopen master core: host registers, the 14-state FSM, the services and the datapath
--   around the FSM. It talks to the MCP2510 only through mcp2510_ctrl's frame interface.
-- Purpose:
--   * canopen_host_regs: Avalon-MM slave and interrupt (register map: docs/register_map.md).
--   * canopen_master_fsm: the scheduler (St0..St13, docs/fsm.md). Every condition it sees is
--     computed here; every action it asks for (its Moore state outputs) is carried out here.
--   * canopen_sdo_channels (St6/St9: N_SDO SDO clients, transfers to different nodes
--     interleave), canopen_node_monitor (St7/St10: heartbeat, guarding, boot-up, EMCY),
--     canopen_autoconfig (the SDO configuration list; owns SDO channel 0 while it runs, its NMT
--     starts wait in their own register and go out in St10).
--   * canopen_sync_timebase: timebase (us/ms), SYNC producer, synchronous window.
--   * canopen_fault_supervisor: error latch (St13), state watchdog (bounded waits), controller
--     re-initialisation (St0), CAN status snapshot.
--   * canopen_tx_path: generation sources (St2, St8..St10), Transmit_Data with the TX buffer
--     plan (St11), the controller request (St12), SDO withdrawal and sync TPDO cancel.
--   * Datapath (this file): Receive_Data and COB-ID classifier (St3/St4), the FSM conditions,
--     event and counter strobes. Receive_Data is the head of the controller's RX FIFO (a block
--     RAM output register), not a copy: St3 takes a base frame by leaving it at the head, and
--     the head is popped at the edge where the FSM leaves St4..St7 (rx_release).
--   TX buffer plan: TXB2 (TXP 3) holds the next SYNC, preloaded in St2..St12 and started by the
--   TX2RTS pin at the exact period, so its start never waits for SPI traffic; TXB1 (TXP 2)
--   carries SDO and NMT; TXB0 (TXP 1) PDOs. A generation (also a reply of St5..St7, St13) is
--   only dispatched when its buffer is free, so St12 never waits behind a pending transmission
--   and the FSM keeps reading received frames while a frame waits for its buffer.
--   canopen_pdo_engine handles St5 (received PDOs, RTRs on the master's PDOs) and St8 (PDOs
--   due: synchronous after SYNC within the synchronous window, event, RTR replies, RPDO polls).
-- =================================================================================================

library ieee;
    use ieee.std_logic_1164.all;
    use ieee.numeric_std.all;

library work;
    use work.canopen_pkg.all;
    use work.canopen_master_pkg.all;
    use work.canopen_util_pkg.all;
    use work.mcp2510_pkg.all;

entity canopen_master_core is
    generic (
        CLK_FREQ_HZ       : positive                := 50_000_000; -- clk_i frequency [Hz]
        MAX_NODES         : positive range 1 to 16  := 8;          -- monitored node slots
        EMCY_DEPTH        : positive range 2 to 64  := 8;          -- EMCY FIFO entries
        SDO_BUF_BYTES     : positive                := 256;        -- SDO transfer buffer [bytes]
        N_SDO             : positive range 1 to 4   := 2;          -- SDO client channels
        N_TPDO            : positive range 1 to 32  := 8;          -- PDO channels sent
        N_RPDO            : positive range 1 to 32  := 8;          -- PDO channels received
        CFG_DEPTH         : positive range 2 to 256 := 64;         -- configuration list entries
        CAN_BITRATE_BPS   : positive                := 1_000_000;  -- for Omni-ID feasibility
        OMNI_ENABLE       : boolean                 := true;       -- build the Omni-ID engine
        WATCHDOG_US       : positive                := 20_000;     -- longest wait in one state
        REINIT_BACKOFF_MS : positive                := 100         -- between init attempts
    );
    port (
        -- clock and reset
        clk_i   : in    std_logic; -- system clock
        rst_n_i : in    std_logic; -- async reset, active low (synchronised release)
        -- host: Avalon-MM slave, word addressing, read latency 1
        avs_address_i       : in    std_logic_vector(7 downto 0);  -- word address
        avs_read_i          : in    std_logic;                     -- read strobe
        avs_write_i         : in    std_logic;                     -- write strobe
        avs_writedata_i     : in    std_logic_vector(31 downto 0); -- write data
        avs_byteenable_i    : in    std_logic_vector(3 downto 0);  -- byte enables
        avs_readdata_o      : out   std_logic_vector(31 downto 0); -- read data
        avs_readdatavalid_o : out   std_logic;                     -- read data valid
        irq_o               : out   std_logic;                     -- interrupt, active high
        -- debug
        fsm_state_o : out   std_logic_vector(3 downto 0); -- FSM state (St number)
        -- mcp2510_ctrl: control and status
        ctl_reinit_o    : out   std_logic;                    -- pulse: re-initialise
        ctl_init_done_i : in    std_logic;                    -- chip in normal mode
        ctl_init_fail_i : in    std_logic;                    -- initialisation failed
        ctl_chip_lost_i : in    std_logic;                    -- strobe: chip reset found
        ctl_busy_i      : in    std_logic;                    -- SPI sequence running
        ctl_tec_i       : in    std_logic_vector(7 downto 0); -- live TEC (0 after RESET)
        ctl_rec_i       : in    std_logic_vector(7 downto 0); -- live REC (0 after RESET)
        ctl_eflg_i      : in    std_logic_vector(7 downto 0); -- live EFLG (0 after RESET)
        -- mcp2510_ctrl: transmit
        ctl_tx_valid_o   : out   std_logic;                     -- request
        ctl_tx_ready_i   : in    std_logic;                     -- request taken
        ctl_tx_buf_o     : out   std_logic_vector(1 downto 0);  -- TX buffer
        ctl_tx_txp_o     : out   std_logic_vector(1 downto 0);  -- priority
        ctl_tx_send_o    : out   std_logic;                     -- RTS after load
        ctl_tx_id_o      : out   std_logic_vector(28 downto 0); -- identifier
        ctl_tx_rtr_o     : out   std_logic;                     -- remote frame
        ctl_tx_dlc_o     : out   std_logic_vector(3 downto 0);  -- DLC
        ctl_tx_data_o    : out   std_logic_vector(63 downto 0); -- data
        ctl_tx_fire_o    : out   std_logic_vector(2 downto 0);  -- pulse: TXnRTS
        ctl_tx_cancel_o  : out   std_logic_vector(2 downto 0);  -- pulse: cancel pending buffer
        ctl_tx_loaded_i  : in    std_logic;                     -- strobe: executed
        ctl_tx_busy_i    : in    std_logic;                     -- the frame is being written
        ctl_tx_pending_i : in    std_logic_vector(2 downto 0);  -- TXREQ per buffer
        ctl_tx_done_i    : in    std_logic_vector(2 downto 0);  -- strobe: sent
        ctl_tx_err_i     : in    std_logic_vector(2 downto 0);  -- strobe: TXERR
        ctl_tx_errors_i  : in    std_logic;                     -- strobe: own frame destroyed
        ctl_tx_drop_i    : in    std_logic_vector(2 downto 0);  -- strobe: fire not loaded
        ctl_tx_aborted_i : in    std_logic_vector(2 downto 0);  -- strobe: cancelled, not sent
        -- mcp2510_ctrl: receive
        ctl_rx_valid_i : in    std_logic;                     -- FIFO head valid
        ctl_rx_ready_o : out   std_logic;                     -- pop
        ctl_rx_id_i    : in    std_logic_vector(28 downto 0); -- identifier
        ctl_rx_ide_i   : in    std_logic;                     -- extended
        ctl_rx_rtr_i   : in    std_logic;                     -- remote frame
        ctl_rx_dlc_i   : in    std_logic_vector(3 downto 0);  -- DLC
        ctl_rx_data_i  : in    std_logic_vector(63 downto 0); -- data
        -- mcp2510_ctrl: interrupts
        ctl_int_valid_i   : in    std_logic;                    -- strobe: INT handled
        ctl_int_canintf_i : in    std_logic_vector(7 downto 0); -- CANINTF
        ctl_int_eflg_i    : in    std_logic_vector(7 downto 0); -- EFLG
        ctl_rx_overflow_i : in    std_logic_vector(1 downto 0)  -- strobe: frame lost
    );
end entity canopen_master_core;

architecture rtl of canopen_master_core is

    -- ---------------------------------------------------------------------------------------------
    -- Configuration check and constants
    -- ---------------------------------------------------------------------------------------------

    function check_config return boolean is
    begin

        assert CLK_FREQ_HZ mod 1_000_000 = 0
            report "canopen_master: CLK_FREQ_HZ must be a whole number of MHz for exact us timing"
            severity failure;
        return true;

    end function check_config;

    constant config_ok_c : boolean := check_config;

    -- ---------------------------------------------------------------------------------------------
    -- Host register block interface
    -- ---------------------------------------------------------------------------------------------
    signal sync_en        : std_logic;
    signal host_reinit    : std_logic;
    signal nmt_req        : std_logic;
    signal nmt_cs         : std_logic_vector(7 downto 0);
    signal nmt_node       : std_logic_vector(7 downto 0);
    signal sync_period_us : std_logic_vector(31 downto 0);
    signal sync_overflow  : std_logic_vector(7 downto 0);
    signal sync_window_us : std_logic_vector(31 downto 0);
    signal cfg_node       : std_logic_vector(7 * MAX_NODES - 1 downto 0);
    signal cfg_mode       : std_logic_vector(2 * MAX_NODES - 1 downto 0);
    -- NODE_TIME write port (host block -> node monitor's time RAM)
    signal cfg_tl_we      : std_logic;
    signal cfg_tl_slot    : std_logic_vector(4 downto 0);
    signal cfg_tl_time    : std_logic_vector(15 downto 0);
    signal cfg_tl_life    : std_logic_vector(7 downto 0);
    signal cfg_tl_ok      : std_logic_vector(MAX_NODES - 1 downto 0);
    signal cfg_autostart  : std_logic_vector(MAX_NODES - 1 downto 0);
    signal cfg_reset_loss : std_logic_vector(MAX_NODES - 1 downto 0);
    signal node_clear     : std_logic_vector(MAX_NODES - 1 downto 0);
    signal emcy_clear     : std_logic;
    signal emcy_pop       : std_logic;
    signal sdo_req        : std_logic;
    signal sdo_upload     : std_logic;
    signal sdo_node       : std_logic_vector(7 downto 0);
    signal sdo_index      : std_logic_vector(15 downto 0);
    signal sdo_subindex   : std_logic_vector(7 downto 0);
    signal sdo_size       : std_logic_vector(10 downto 0);
    signal sdo_timeout_ms : std_logic_vector(15 downto 0);
    signal sdo_cob_req    : std_logic_vector(10 downto 0);
    signal sdo_cob_resp   : std_logic_vector(10 downto 0);
    signal sdo_buf_addr   : std_logic_vector(7 downto 0);
    signal sdo_buf_we     : std_logic;
    signal sdo_buf_wdata  : std_logic_vector(31 downto 0);
    signal sdo_buf_rdata  : std_logic_vector(31 downto 0);
    signal sdo_chan       : std_logic_vector(1 downto 0);
    signal acfg_fail_sel  : std_logic_vector(3 downto 0);

    -- ---------------------------------------------------------------------------------------------
    -- FSM interface
    -- ---------------------------------------------------------------------------------------------
    signal fsm_state    : std_logic_vector(3 downto 0);
    signal state_change : std_logic;
    signal in_init      : std_logic;
    signal in_sync_gen  : std_logic;
    signal in_rx        : std_logic;
    signal in_parse     : std_logic;
    signal in_pdo_proc  : std_logic;
    signal in_sdo_proc  : std_logic;
    signal in_nmt_proc  : std_logic;
    signal in_pdo_gen   : std_logic;
    signal in_sdo_gen   : std_logic;
    signal in_nmt_gen   : std_logic;
    signal in_encap     : std_logic;
    signal in_tx        : std_logic;
    signal in_error     : std_logic;
    signal err_pending  : std_logic;
    signal sync_due     : std_logic;
    signal nmt_gen_req  : std_logic;
    signal sdo_gen_req  : std_logic;
    signal pdo_gen_req  : std_logic;
    signal rx_head_ok   : std_logic;
    signal cls_pdo      : std_logic;
    signal cls_sdo      : std_logic;
    signal cls_nmt      : std_logic;
    signal frame_ready  : std_logic;
    signal gen_ready    : std_logic;
    signal encap_ok     : std_logic;
    signal err_fatal    : std_logic;
    signal err_nmt      : std_logic;
    signal watchdog     : std_logic;
    -- replies of St5..St7 (T11, T13, T15) only while their TX buffer is free
    signal pdo_reply_now : std_logic;
    signal sdo_reply_now : std_logic;
    signal nmt_reply_now : std_logic;

    -- ---------------------------------------------------------------------------------------------
    -- Datapath registers
    -- ---------------------------------------------------------------------------------------------
    -- timebase
    signal tick_us : std_logic;
    signal tick_ms : std_logic;
    signal time_us : std_logic_vector(31 downto 0);
    signal time_ms : std_logic_vector(31 downto 0);
    -- Receive_Data (thesis: 13-byte frame register filled in St3): the RX FIFO head, held there
    -- from St3 until the FSM leaves St4..St7
    signal rx_frame : can_frame_t;
    -- the last cycle of St4..St7 (a received frame in process): pop the head
    signal rx_release : std_logic;
    -- transmit path (canopen_tx_path): an SDO transfer ended (canopen_sdo_channels
    -- wdr_req_o / wdr_id_o) and its acknowledge; the SDO frame is an abort; TXB0's cancelled
    -- frame was a synchronous TPDO (for the PDO engine's late count)
    signal sdo_wdr_req     : std_logic;
    signal sdo_wdr_id      : std_logic_vector(10 downto 0);
    signal sdo_wdr_ack     : std_logic;
    signal sdo_tx_abort    : std_logic;
    signal pdo_cancel_sent : std_logic;
    -- host NMT command waiting (the configuration list's: acfg_nmt_pending)
    signal nmt_pending : std_logic;
    -- SYNC producer (canopen_sync_timebase): TXB2 holds a valid SYNC, fire strobe, the
    -- counter byte to preload, what the PDOs belong to, SYNCs fired, us into the period + 1; its
    -- two strobes from St12 (TXB2 loaded with the SYNC) and St2 (a SYNC frame built)
    signal sync_loaded    : std_logic;
    signal sync_counter   : std_logic_vector(7 downto 0);
    signal sync_count     : std_logic_vector(31 downto 0);
    signal sync_sent      : std_logic_vector(7 downto 0);
    signal sync_fire      : std_logic;
    signal sync_next      : std_logic_vector(31 downto 0);
    signal sync_load_done : std_logic;
    signal sync_encap     : std_logic;
    -- the SYNC timer is in the second half of the period (SYNC_PERIOD_US / 2 or later): the
    -- Omni-ID preload waits for it (registered: one cycle after the timer gets there)
    signal sync_half        : std_logic;
    signal sync_period_half : unsigned(31 downto 0);
    -- sync_fire one cycle later: the TX2RTS pulse is in flight, TXB2 not yet shown pending
    signal sync_fire_q : std_logic;
    -- fault supervisor (canopen_fault_supervisor): error latch (St13), re-initialisation
    -- (St0), init_done as the FSM sees it, CAN status snapshot for the host; its inputs that
    -- VHDL-93 cannot compute in the port map
    signal err_can       : std_logic;
    signal err_busoff    : std_logic;
    signal err_reinit    : std_logic;
    signal err_node      : std_logic;
    signal err_chip      : std_logic;
    signal init_done_fsm : std_logic;
    signal can_tec       : std_logic_vector(7 downto 0);
    signal can_rec       : std_logic_vector(7 downto 0);
    signal can_eflg      : std_logic_vector(7 downto 0);
    signal fs_errif      : std_logic;
    signal fs_rx_ovf     : std_logic;
    signal fs_tx_fault   : std_logic;
    signal fs_node_err   : std_logic;
    -- FIFO pop: an extended frame in St3, or the processed frame (rx_release)
    signal rx_pop : std_logic;
    -- entry strobes into the processing states
    signal enter_sdo : std_logic;
    signal enter_nmt : std_logic;

    -- ---------------------------------------------------------------------------------------------
    -- Service blocks
    -- ---------------------------------------------------------------------------------------------
    signal sdo_busy       : std_logic;
    signal sdo_error      : std_logic;
    signal sdo_abort_sent : std_logic;
    signal sdo_abort_code : std_logic_vector(31 downto 0);
    signal sdo_xfer_size  : std_logic_vector(10 downto 0);
    signal sdo_tx_req     : std_logic;
    signal sdo_tx_id      : std_logic_vector(10 downto 0);
    signal sdo_tx_dlc     : std_logic_vector(3 downto 0);
    signal sdo_tx_data    : std_logic_vector(63 downto 0);
    signal sdo_tx_ack     : std_logic;
    signal sdo_rx_done    : std_logic;
    signal sdo_rx_reply   : std_logic;
    signal sdo_rx_unexp   : std_logic;
    -- SDO channels: the received frame carries a running transfer's response COB-ID
    signal sdo_rx_match : std_logic;
    signal sdo_refused  : std_logic;
    -- per channel (bit c): busy, host transfer done
    signal sdo_ch_busy : std_logic_vector(3 downto 0);
    signal sdo_ch_done : std_logic_vector(3 downto 0);
    signal sdo_ch_go   : std_logic_vector(3 downto 0);
    -- one strobe per aborted transfer (channels ending together are counted one by one)
    signal sdo_cnt_abort : std_logic;
    -- channel 0 as seen by the configuration list
    signal sdo_own_idle  : std_logic;
    signal sdo_own_done  : std_logic;
    signal sdo_own_error : std_logic;
    signal sdo_own_abort : std_logic_vector(31 downto 0);

    -- automatic configuration (canopen_autoconfig)
    signal acfg_start       : std_logic;
    signal acfg_start_nodes : std_logic;
    signal acfg_start_pend  : std_logic;
    signal acfg_run         : std_logic;
    -- sticky: the last ACFG_CTRL.START was refused (list running, or Omni-ID mode)
    signal acfg_refused : std_logic;
    signal acfg_busy    : std_logic;
    -- the configuration list starts (pending start, own SDO channel idle, list not running)
    signal acfg_go : std_logic;
    -- the list's NMT start can be queued (no earlier one waiting)
    signal acfg_nmt_ready  : std_logic;
    signal acfg_done       : std_logic;
    signal acfg_tbl_we     : std_logic;
    signal acfg_tbl_addr   : std_logic_vector(7 downto 0);
    signal acfg_tbl_node   : std_logic_vector(6 downto 0);
    signal acfg_tbl_index  : std_logic_vector(15 downto 0);
    signal acfg_tbl_sub    : std_logic_vector(7 downto 0);
    signal acfg_tbl_size   : std_logic_vector(2 downto 0);
    signal acfg_tbl_value  : std_logic_vector(31 downto 0);
    signal acfg_nodes_ok   : std_logic_vector(7 downto 0);
    signal acfg_nodes_fail : std_logic_vector(7 downto 0);
    signal acfg_fail_node  : std_logic_vector(6 downto 0);
    signal acfg_fail_entry : std_logic_vector(7 downto 0);
    signal acfg_fail_abort : std_logic_vector(31 downto 0);
    signal acfg_sdo_req    : std_logic;
    signal acfg_sdo_node   : std_logic_vector(6 downto 0);
    signal acfg_sdo_index  : std_logic_vector(15 downto 0);
    signal acfg_sdo_sub    : std_logic_vector(7 downto 0);
    signal acfg_sdo_size   : std_logic_vector(10 downto 0);
    signal acfg_buf_we     : std_logic;
    signal acfg_buf_wdata  : std_logic_vector(31 downto 0);
    signal acfg_nmt_req    : std_logic;
    signal acfg_nmt_node   : std_logic_vector(6 downto 0);
    -- its NMT start waits in canopen_tx_path (apart from the host's NMT command)
    signal acfg_nmt_pending : std_logic;

    -- node status RAM of the monitor, read by the host registers: slot, which word (NMT state or
    -- last time), the word
    signal node_st_slot     : std_logic_vector(4 downto 0);
    signal node_st_nmt      : std_logic;
    signal node_st_data     : std_logic_vector(31 downto 0);
    signal st_alive         : std_logic_vector(MAX_NODES - 1 downto 0);
    signal st_lost          : std_logic_vector(MAX_NODES - 1 downto 0);
    signal st_toggle        : std_logic_vector(MAX_NODES - 1 downto 0);
    signal st_bootup        : std_logic_vector(MAX_NODES - 1 downto 0);
    signal ev_lost          : std_logic_vector(MAX_NODES - 1 downto 0);
    signal ev_toggle        : std_logic_vector(MAX_NODES - 1 downto 0);
    signal ev_bootup        : std_logic_vector(MAX_NODES - 1 downto 0);
    signal ev_emcy          : std_logic;
    signal emcy_count       : std_logic_vector(6 downto 0);
    signal emcy_lost        : std_logic;
    signal emcy_node        : std_logic_vector(6 downto 0);
    signal emcy_data        : std_logic_vector(63 downto 0);
    signal emcy_time        : std_logic_vector(31 downto 0);
    signal mon_tx_req       : std_logic;
    signal mon_tx_id        : std_logic_vector(10 downto 0);
    signal mon_tx_rtr       : std_logic;
    signal mon_tx_dlc       : std_logic_vector(3 downto 0);
    signal mon_tx_data      : std_logic_vector(63 downto 0);
    signal mon_tx_ack       : std_logic;
    signal mon_rx_done      : std_logic;
    signal mon_rx_reply     : std_logic;
    signal mon_rx_unexp     : std_logic;
    signal mon_rx_malformed : std_logic;

    -- events and counter strobes towards the host block
    -- PDO engine
    signal pdo_reg_addr  : std_logic_vector(5 downto 0);
    signal pdo_reg_we    : std_logic;
    signal pdo_reg_wdata : std_logic_vector(31 downto 0);
    signal pdo_reg_rdata : std_logic_vector(31 downto 0);
    signal pdo_tx_req    : std_logic;
    signal pdo_tx_id     : std_logic_vector(10 downto 0);
    signal pdo_tx_rtr    : std_logic;
    signal pdo_tx_dlc    : std_logic_vector(3 downto 0);
    signal pdo_tx_data   : std_logic_vector(63 downto 0);
    signal pdo_tx_ack    : std_logic;
    signal pdo_rx_done   : std_logic;
    signal pdo_rx_reply  : std_logic;
    signal pdo_rx_unexp  : std_logic;
    -- the PDO engine's own outputs (pdo_* above are the active protocol engine's)
    signal pe_reg_rdata : std_logic_vector(31 downto 0);
    signal pe_tx_req    : std_logic;
    signal pe_tx_id     : std_logic_vector(10 downto 0);
    signal pe_tx_rtr    : std_logic;
    signal pe_tx_dlc    : std_logic_vector(3 downto 0);
    signal pe_tx_data   : std_logic_vector(63 downto 0);
    signal pe_rx_done   : std_logic;
    signal pe_rx_reply  : std_logic;
    signal pe_rx_unexp  : std_logic;

    -- Omni-ID mode: CTRL.OMNI as written, and in effect (only with the engine built)
    signal omni_req     : std_logic;
    signal omni_en      : std_logic;
    signal om_reg_rdata : std_logic_vector(31 downto 0);
    signal om_tx_req    : std_logic;
    signal om_tx_id     : std_logic_vector(10 downto 0);
    signal om_tx_rtr    : std_logic;
    signal om_tx_dlc    : std_logic_vector(3 downto 0);
    signal om_tx_data   : std_logic_vector(63 downto 0);
    signal om_rx_done   : std_logic;
    signal om_rx_reply  : std_logic;
    signal om_rx_unexp  : std_logic;
    signal om_cyc_id    : std_logic_vector(10 downto 0);
    signal om_cyc_dlc   : std_logic_vector(3 downto 0);
    signal om_cyc_data  : std_logic_vector(63 downto 0);
    signal om_cyc_take  : std_logic;
    signal om_feasible  : std_logic;
    signal om_ev        : std_logic;
    -- Omni-ID: the cycle frame is preloaded in the second half of the period, so set-points
    -- committed before the middle of a cycle go out at the next cycle instant
    signal om_preload_ok : std_logic;
    signal enter_pdo     : std_logic;
    -- synchronous window (1007h semantics): open from each SYNC for SYNC_WINDOW_US, 0 = always
    signal window_open : std_logic;
    -- block inputs gated by the protocol mode (CTRL.OMNI): the PDO engine and the node monitor
    -- run in CANopen mode, the Omni-ID engine in Omni-ID mode
    signal mon_enable      : std_logic;
    signal pe_sync         : std_logic;
    signal pe_reg_we       : std_logic;
    signal pe_rx_valid     : std_logic;
    signal pe_tx_ack       : std_logic;
    signal pe_tx_sync      : std_logic;
    signal pe_tx_cancelled : std_logic;
    signal om_cycle        : std_logic;
    signal om_reg_we       : std_logic;
    signal om_rx_valid     : std_logic;
    signal om_tx_ack       : std_logic;

    signal ev_node_any    : std_logic;
    signal ev_can_error   : std_logic;
    signal ev_frame_error : std_logic;
    signal ev_init        : std_logic;
    signal cnt_unexpected : std_logic;
    signal cnt_rx_frame   : std_logic;
    signal cnt_tx_frame   : std_logic;
    signal cnt_tx_error   : std_logic;
    signal cnt_can_error  : std_logic;
    -- counter strobes for the host block that VHDL-93 cannot compute in the port map
    signal cnt_malformed : std_logic;
    signal cnt_hb_loss   : std_logic;
    signal cnt_guard_err : std_logic;
    -- host view of the error-passive state (EFLG RXEP or TXEP) and of the node events
    signal can_err_passive : std_logic;
    signal host_ev_node    : std_logic;

    -- ---------------------------------------------------------------------------------------------
    -- Host input validation (docs/register_map.md, REFUSED bits)
    -- ---------------------------------------------------------------------------------------------
    -- NMT_CMD: CS is one of the five CiA 301 commands and NODE is 0..127; the request is
    -- accepted; REFUSED as the host reads it (the decision already in the cycle of the request)
    signal nmt_ref_view : std_logic;
    -- ACFG_STATUS.REFUSED as the host reads it
    signal acfg_ref_view : std_logic;
    -- the EMCY FIFO head as the host sees it: 0 while the FIFO is empty (its RAM has no reset)
    signal emcy_head_ok : std_logic;
    signal emcy_node_h  : std_logic_vector(6 downto 0);
    signal emcy_data_h  : std_logic_vector(63 downto 0);
    signal emcy_time_h  : std_logic_vector(31 downto 0);

    function node_id_ok (id : cob_id_t) return boolean is
    begin

        return node_of(id) /= "0000000";

    end function node_id_ok;

begin

    -- ---------------------------------------------------------------------------------------------
    -- Time base and SYNC producer (exact period, counter byte, synchronous window)
    -- ---------------------------------------------------------------------------------------------
    -- (sync_load_done: St12 loaded TXB2 with the SYNC, sync_encap: St11 takes the SYNC source;
    -- both from canopen_tx_path)
    sync_tb_inst : entity work.canopen_sync_timebase
        generic map (
            CLK_FREQ_HZ => CLK_FREQ_HZ
        )
        port map (
            clk_i            => clk_i,
            rst_n_i          => rst_n_i,
            tick_us_o        => tick_us,
            tick_ms_o        => tick_ms,
            time_us_o        => time_us,
            time_ms_o        => time_ms,
            sync_en_i        => sync_en,
            sync_period_us_i => sync_period_us,
            sync_overflow_i  => sync_overflow,
            sync_window_us_i => sync_window_us,
            load_done_i      => sync_load_done,
            encap_sync_i     => sync_encap,
            init_done_i      => ctl_init_done_i,
            sync_loaded_o    => sync_loaded,
            sync_fire_o      => sync_fire,
            sync_fire_q_o    => sync_fire_q,
            sync_counter_o   => sync_counter,
            sync_sent_o      => sync_sent,
            sync_count_o     => sync_count,
            sync_next_o      => sync_next,
            window_open_o    => window_open
        );

    -- ---------------------------------------------------------------------------------------------
    -- FSM conditions
    -- ---------------------------------------------------------------------------------------------
    -- sync_due: in the cycle after a fire, sync_loaded is already 0 but the controller shows
    -- TXB2 pending only one cycle later: without sync_fire_q, St2..St12 could preload TXB2
    -- behind the SYNC just started and St12 wait for its transmission (fuzz finding 2)
    err_pending <= err_can or err_busoff or err_reinit or err_node or err_chip;
    sync_due    <= sync_en and or_reduce(sync_period_us) and not sync_loaded and not sync_fire_q
                   and not ctl_tx_pending_i(2) and (not omni_en or om_preload_ok);
    -- half the period, compared with the timer's next value (sync_next) in the clocked process
    -- (sync_half)
    sync_period_half <= shift_right(unsigned(sync_period_us), 1);
    om_preload_ok    <= om_feasible and sync_half;
    -- (nmt_gen_req, sdo_gen_req, pdo_gen_req, frame_ready: canopen_tx_path; a generation is
    -- only dispatched when its TX buffer is free.) The same for the replies of St5..St7 and
    -- St13 (T11, T13, T15, T28): with the buffer still pending (its frame loses arbitration on a
    -- busy bus) the reply stays requested in its source and the FSM returns to St1 (T24, T25,
    -- T26, T27), which keeps reading the controller's RX FIFO and sends the reply by T20..T22
    -- once the buffer is free; St12 never waits for a transmission to end (fuzz finding 2: RX
    -- overflow while St12 waited)
    pdo_reply_now <= pdo_rx_reply and not ctl_tx_pending_i(0);
    sdo_reply_now <= sdo_rx_reply and not ctl_tx_pending_i(1);
    nmt_reply_now <= mon_rx_reply and not ctl_tx_pending_i(1);

    -- St3: CANopen uses base frames; an extended frame is dropped (T6) and counted
    rx_head_ok <= not ctl_rx_ide_i;

    -- St4: classification of Receive_Data by function code (CiA 301 predefined connection set)
    classify_proc : process (omni_en, rx_frame, sdo_rx_match) is

        variable fc : func_code_t;

    begin

        fc      := func_code(rx_frame.id);
        cls_pdo <= '0';
        cls_sdo <= '0';
        cls_nmt <= '0';

        if omni_en = '1' then
            -- Omni-ID mode: one protocol per bus, every frame goes to the Omni-ID engine (St5)
            cls_pdo <= '1';
        elsif node_id_ok(rx_frame.id) then
            -- slaves' TPDOs, and RTRs (or other masters' frames) on RPDO COB-IDs: the PDO
            -- engine matches them against its channels
            if fc = FC_TPDO1_C or fc = FC_TPDO2_C or fc = FC_TPDO3_C or fc = FC_TPDO4_C
               or fc = FC_RPDO1_C or fc = FC_RPDO2_C or fc = FC_RPDO3_C or fc = FC_RPDO4_C then
                cls_pdo <= '1';
            elsif fc = FC_SDO_TX_C or sdo_rx_match = '1' then
                cls_sdo <= '1';
            elsif fc = FC_NMT_EC_C or fc = FC_SYNC_EMCY_C then
                cls_nmt <= '1';
            end if;
        elsif sdo_rx_match = '1' then
            -- a configured response COB-ID outside 580h..5FFh of a running transfer
            cls_sdo <= '1';
        end if;

    end process classify_proc;

    -- EMCY FIFO head towards the host: defined (0) while the FIFO is empty
    emcy_head_ok <= '1' when unsigned(emcy_count) /= 0 else
                    '0';
    emcy_node_h  <= emcy_node when emcy_head_ok = '1' else
                    (others => '0');
    emcy_data_h  <= emcy_data when emcy_head_ok = '1' else
                    (others => '0');
    emcy_time_h  <= emcy_time when emcy_head_ok = '1' else
                    (others => '0');

    encap_ok <= in_encap;

    -- St11 rewrites Transmit_Data, which the controller reads while it writes the TX buffer
    -- (ctl_tx_busy_i: it keeps no copy): a generation state (St2, St8..St10) waits for the end
    -- of that write. St12 is only left by the load (ctl_tx_busy_i already 0) or by the
    -- watchdog, so only the second case ever waits here.
    gen_ready <= frame_ready and not ctl_tx_busy_i;

    -- St13: a bus-off or a host request re-initialises the controller (G1); an NMT frame queued
    -- by the node monitor after a node error is sent right away (T28) if TXB1 is free, else
    -- from St1 (T22) once it is
    err_fatal <= err_busoff or err_reinit or err_chip;
    err_nmt   <= err_node and mon_tx_req and not ctl_tx_pending_i(1);

    -- ---------------------------------------------------------------------------------------------
    -- Datapath: Receive_Data (St3), the registered SYNC half-period condition
    -- ---------------------------------------------------------------------------------------------
    -- Receive_Data: the RX FIFO head (the controller's FIFO keeps it, unchanged, until the pop)
    rx_frame.id   <= ctl_rx_id_i(10 downto 0);
    rx_frame.rtr  <= ctl_rx_rtr_i;
    rx_frame.dlc  <= ctl_rx_dlc_i;
    rx_frame.data <= ctl_rx_data_i;

    -- the edge that leaves St4..St7 pops the frame just processed: St4 without a class (G3),
    -- St5..St7 when their block is done (T11/T13/T15, T24..T26) or on the watchdog (G4). These
    -- are the FSM's exit conditions of those states (rx_release_check_proc compares them).
    rx_release <= '1' when in_parse = '1' and cls_pdo = '0' and cls_sdo = '0' and cls_nmt = '0' else
                  '1' when in_pdo_proc = '1' and (pdo_rx_done = '1' or watchdog = '1') else
                  '1' when in_sdo_proc = '1' and (sdo_rx_done = '1' or watchdog = '1') else
                  '1' when in_nmt_proc = '1' and (mon_rx_done = '1' or watchdog = '1') else
                  '0';
    -- St3 drops an extended frame at once (T6); a base frame stays at the head (T7)
    rx_pop         <= '1' when in_rx = '1' and ctl_rx_valid_i = '1' and rx_head_ok = '0' else
                      rx_release;
    ctl_rx_ready_o <= rx_pop;

    -- simulation only: rx_release is 1 exactly in the last cycle of St4..St7
    -- pragma translate_off
    rx_release_check_proc : process (clk_i) is

        variable proc_q  : std_logic := '0';
        variable rel_q   : std_logic := '0';
        variable in_proc : std_logic;

    begin

        if rising_edge(clk_i) then
            in_proc := in_parse or in_pdo_proc or in_sdo_proc or in_nmt_proc;
            if rst_n_i = '1' and proc_q = '1' then
                assert (rel_q = '1') = (in_proc = '0')
                    report "canopen_master_core: rx_release does not match the FSM leaving St4..St7"
                    severity failure;
            end if;
            proc_q := in_proc;
            rel_q  := rx_release;
        end if;

    end process rx_release_check_proc;

    -- pragma translate_on

    datapath_proc : process (clk_i, rst_n_i) is
    begin

        if rst_n_i = '0' then
            sync_half <= '0';
        elsif rising_edge(clk_i) then
            -- us into the period >= half, i.e. half < sync_next (split compare: two 16-bit
            -- halves side by side, canopen_util_pkg; registered, so the FSM's SYNC condition
            -- starts at a register)
            sync_half <= '0';
            if lt_split(sync_period_half, unsigned(sync_next)) then
                sync_half <= '1';
            end if;
        end if;

    end process datapath_proc;

    -- ---------------------------------------------------------------------------------------------
    -- Transmit path: generation sources, Transmit_Data and the TX buffer plan (St2, St8..St12)
    -- ---------------------------------------------------------------------------------------------
    tx_path_inst : entity work.canopen_tx_path
        port map (
            clk_i              => clk_i,
            rst_n_i            => rst_n_i,
            in_sync_gen_i      => in_sync_gen,
            in_nmt_gen_i       => in_nmt_gen,
            in_sdo_gen_i       => in_sdo_gen,
            in_pdo_gen_i       => in_pdo_gen,
            in_encap_i         => in_encap,
            in_tx_i            => in_tx,
            omni_en_i          => omni_en,
            nmt_req_i          => nmt_req,
            nmt_cs_i           => nmt_cs,
            nmt_node_i         => nmt_node,
            nmt_pending_o      => nmt_pending,
            nmt_refused_o      => nmt_ref_view,
            acfg_nmt_req_i     => acfg_nmt_req,
            acfg_nmt_node_i    => acfg_nmt_node,
            acfg_nmt_pending_o => acfg_nmt_pending,
            sync_overflow_i    => sync_overflow,
            sync_counter_i     => sync_counter,
            cyc_id_i           => om_cyc_id,
            cyc_dlc_i          => om_cyc_dlc,
            cyc_data_i         => om_cyc_data,
            sync_encap_o       => sync_encap,
            sync_loaded_o      => sync_load_done,
            mon_tx_req_i       => mon_tx_req,
            mon_tx_id_i        => mon_tx_id,
            mon_tx_rtr_i       => mon_tx_rtr,
            mon_tx_dlc_i       => mon_tx_dlc,
            mon_tx_data_i      => mon_tx_data,
            mon_tx_ack_o       => mon_tx_ack,
            sdo_tx_req_i       => sdo_tx_req,
            sdo_tx_id_i        => sdo_tx_id,
            sdo_tx_dlc_i       => sdo_tx_dlc,
            sdo_tx_data_i      => sdo_tx_data,
            sdo_tx_abort_i     => sdo_tx_abort,
            sdo_tx_ack_o       => sdo_tx_ack,
            sdo_wdr_req_i      => sdo_wdr_req,
            sdo_wdr_id_i       => sdo_wdr_id,
            sdo_wdr_ack_o      => sdo_wdr_ack,
            pdo_tx_req_i       => pdo_tx_req,
            pdo_tx_id_i        => pdo_tx_id,
            pdo_tx_rtr_i       => pdo_tx_rtr,
            pdo_tx_dlc_i       => pdo_tx_dlc,
            pdo_tx_data_i      => pdo_tx_data,
            pdo_tx_sync_i      => pe_tx_sync,
            pdo_tx_ack_o       => pdo_tx_ack,
            sync_fire_i        => sync_fire,
            pdo_cancel_sent_o  => pdo_cancel_sent,
            nmt_gen_req_o      => nmt_gen_req,
            sdo_gen_req_o      => sdo_gen_req,
            pdo_gen_req_o      => pdo_gen_req,
            frame_ready_o      => frame_ready,
            ctl_tx_ready_i     => ctl_tx_ready_i,
            ctl_tx_loaded_i    => ctl_tx_loaded_i,
            ctl_tx_pending_i   => ctl_tx_pending_i,
            ctl_init_done_i    => ctl_init_done_i,
            ctl_tx_valid_o     => ctl_tx_valid_o,
            ctl_tx_buf_o       => ctl_tx_buf_o,
            ctl_tx_txp_o       => ctl_tx_txp_o,
            ctl_tx_send_o      => ctl_tx_send_o,
            ctl_tx_id_o        => ctl_tx_id_o,
            ctl_tx_rtr_o       => ctl_tx_rtr_o,
            ctl_tx_dlc_o       => ctl_tx_dlc_o,
            ctl_tx_data_o      => ctl_tx_data_o,
            ctl_tx_cancel_o    => ctl_tx_cancel_o
        );

    -- ---------------------------------------------------------------------------------------------
    -- Fault supervisor: error latch (St13), state watchdog, re-initialisation (St0), CAN status
    -- ---------------------------------------------------------------------------------------------
    fs_errif    <= ctl_int_valid_i and ctl_int_canintf_i(MCP_CANINTF_ERRIF_BIT_C);
    fs_rx_ovf   <= or_reduce(ctl_rx_overflow_i);
    fs_tx_fault <= or_reduce(ctl_tx_err_i) or or_reduce(ctl_tx_drop_i);
    fs_node_err <= or_reduce(ev_lost) or or_reduce(ev_toggle);

    fault_inst : entity work.canopen_fault_supervisor
        generic map (
            CAN_BITRATE_BPS   => CAN_BITRATE_BPS,
            WATCHDOG_US       => WATCHDOG_US,
            REINIT_BACKOFF_MS => REINIT_BACKOFF_MS
        )
        port map (
            clk_i          => clk_i,
            rst_n_i        => rst_n_i,
            tick_us_i      => tick_us,
            init_done_i    => ctl_init_done_i,
            init_fail_i    => ctl_init_fail_i,
            chip_lost_i    => ctl_chip_lost_i,
            tec_i          => ctl_tec_i,
            rec_i          => ctl_rec_i,
            eflg_i         => ctl_eflg_i,
            int_errif_i    => fs_errif,
            rx_overflow_i  => fs_rx_ovf,
            tx_fault_i     => fs_tx_fault,
            host_reinit_i  => host_reinit,
            node_error_i   => fs_node_err,
            state_change_i => state_change,
            in_init_i      => in_init,
            in_error_i     => in_error,
            err_can_o      => err_can,
            err_busoff_o   => err_busoff,
            err_reinit_o   => err_reinit,
            err_node_o     => err_node,
            err_chip_o     => err_chip,
            watchdog_o     => watchdog,
            reinit_o       => ctl_reinit_o,
            init_done_o    => init_done_fsm,
            tec_o          => can_tec,
            rec_o          => can_rec,
            eflg_o         => can_eflg,
            ev_init_o      => ev_init
        );

    -- St12: the SYNC in TXB2 is started by TX2RTS at the exact period
    ctl_tx_fire_o <= (2 => sync_fire, others => '0');

    -- entry strobes into the processing states: the service blocks see each frame once
    enter_sdo <= in_sdo_proc and state_change;
    enter_pdo <= in_pdo_proc and state_change;
    enter_nmt <= in_nmt_proc and state_change;

    -- events and counters for the host block
    ev_node_any    <= or_reduce(ev_lost) or or_reduce(ev_toggle) or or_reduce(ev_bootup);
    ev_can_error   <= in_error and (err_can or err_busoff or err_chip);
    cnt_unexpected <= '1' when (in_rx = '1' and ctl_rx_valid_i = '1' and rx_head_ok = '0')
                               or (in_parse = '1' and cls_pdo = '0' and cls_sdo = '0'
                             and cls_nmt = '0')
                                   or (sdo_rx_done = '1' and sdo_rx_unexp = '1')
                                   or (pdo_rx_done = '1' and pdo_rx_unexp = '1')
                                   or (mon_rx_done = '1' and mon_rx_unexp = '1') else
                      '0';
    ev_frame_error <= cnt_unexpected or cnt_malformed;
    cnt_rx_frame   <= rx_pop;
    cnt_tx_frame   <= or_reduce(ctl_tx_done_i);
    -- one per destroyed frame of the master (TEC steps, mcp2510_ctrl terr_proc), and refused
    -- fires of an unloaded buffer
    cnt_tx_error <= ctl_tx_errors_i or or_reduce(ctl_tx_drop_i);
    -- error interrupts (ERRIF) and resets of the chip found by the error poll (chip lost)
    cnt_can_error <= fs_errif or ctl_chip_lost_i;
    cnt_malformed <= mon_rx_done and mon_rx_malformed;
    cnt_hb_loss   <= or_reduce(ev_lost);
    cnt_guard_err <= or_reduce(ev_toggle);

    -- ---------------------------------------------------------------------------------------------
    -- The FSM
    -- ---------------------------------------------------------------------------------------------
    fsm_inst : entity work.canopen_master_fsm
        port map (
            clk_i          => clk_i,
            rst_n_i        => rst_n_i,
            init_done_i    => init_done_fsm,
            init_fail_i    => ctl_init_fail_i,
            err_pending_i  => err_pending,
            rx_avail_i     => ctl_rx_valid_i,
            sync_due_i     => sync_due,
            nmt_req_i      => nmt_gen_req,
            sdo_req_i      => sdo_gen_req,
            pdo_req_i      => pdo_gen_req,
            rx_head_ok_i   => rx_head_ok,
            cls_pdo_i      => cls_pdo,
            cls_sdo_i      => cls_sdo,
            cls_nmt_i      => cls_nmt,
            pdo_done_i     => pdo_rx_done,
            pdo_reply_i    => pdo_reply_now,
            sdo_done_i     => sdo_rx_done,
            sdo_reply_i    => sdo_reply_now,
            nmt_done_i     => mon_rx_done,
            nmt_reply_i    => nmt_reply_now,
            frame_ready_i  => gen_ready,
            encap_ok_i     => encap_ok,
            tx_loaded_i    => ctl_tx_loaded_i,
            err_fatal_i    => err_fatal,
            err_nmt_i      => err_nmt,
            watchdog_i     => watchdog,
            state_o        => fsm_state,
            state_change_o => state_change,
            in_init_o      => in_init,
            in_sync_gen_o  => in_sync_gen,
            in_rx_o        => in_rx,
            in_parse_o     => in_parse,
            in_pdo_proc_o  => in_pdo_proc,
            in_sdo_proc_o  => in_sdo_proc,
            in_nmt_proc_o  => in_nmt_proc,
            in_pdo_gen_o   => in_pdo_gen,
            in_sdo_gen_o   => in_sdo_gen,
            in_nmt_gen_o   => in_nmt_gen,
            in_encap_o     => in_encap,
            in_tx_o        => in_tx,
            in_error_o     => in_error
        );

    fsm_state_o <= fsm_state;

    -- ---------------------------------------------------------------------------------------------
    -- Services
    -- ---------------------------------------------------------------------------------------------
    mon_enable <= not omni_en;

    sdo_inst : entity work.canopen_sdo_channels
        generic map (
            N_SDO     => N_SDO,
            BUF_BYTES => SDO_BUF_BYTES
        )
        port map (
            clk_i           => clk_i,
            rst_n_i         => rst_n_i,
            tick_ms_i       => tick_ms,
            enable_i        => mon_enable,
            host_chan_i     => sdo_chan,
            host_req_i      => sdo_req,
            host_upload_i   => sdo_upload,
            host_node_i     => sdo_node,
            host_index_i    => sdo_index,
            host_sub_i      => sdo_subindex,
            host_size_i     => sdo_size,
            host_cob_req_i  => sdo_cob_req,
            host_cob_rsp_i  => sdo_cob_resp,
            timeout_ms_i    => sdo_timeout_ms,
            buf_addr_i      => sdo_buf_addr,
            buf_we_i        => sdo_buf_we,
            buf_wdata_i     => sdo_buf_wdata,
            buf_rdata_o     => sdo_buf_rdata,
            busy_o          => sdo_busy,
            error_o         => sdo_error,
            abort_code_o    => sdo_abort_code,
            abort_sent_o    => sdo_abort_sent,
            size_o          => sdo_xfer_size,
            refused_o       => sdo_refused,
            chan_busy_o     => sdo_ch_busy,
            chan_done_o     => sdo_ch_done,
            chan_go_o       => sdo_ch_go,
            cnt_abort_o     => sdo_cnt_abort,
            own_i           => acfg_run,
            own_req_i       => acfg_sdo_req,
            own_node_i      => acfg_sdo_node,
            own_index_i     => acfg_sdo_index,
            own_sub_i       => acfg_sdo_sub,
            own_size_i      => acfg_sdo_size,
            own_buf_we_i    => acfg_buf_we,
            own_buf_data_i  => acfg_buf_wdata,
            own_idle_o      => sdo_own_idle,
            own_done_o      => sdo_own_done,
            own_error_o     => sdo_own_error,
            own_abort_o     => sdo_own_abort,
            tx_req_o        => sdo_tx_req,
            tx_id_o         => sdo_tx_id,
            tx_dlc_o        => sdo_tx_dlc,
            tx_data_o       => sdo_tx_data,
            tx_ack_i        => sdo_tx_ack,
            tx_abort_o      => sdo_tx_abort,
            wdr_req_o       => sdo_wdr_req,
            wdr_id_o        => sdo_wdr_id,
            wdr_ack_i       => sdo_wdr_ack,
            rx_match_o      => sdo_rx_match,
            rx_valid_i      => enter_sdo,
            rx_id_i         => rx_frame.id,
            rx_rtr_i        => rx_frame.rtr,
            rx_dlc_i        => rx_frame.dlc,
            rx_data_i       => rx_frame.data,
            rx_done_o       => sdo_rx_done,
            rx_reply_o      => sdo_rx_reply,
            rx_unexpected_o => sdo_rx_unexp
        );

    monitor_inst : entity work.canopen_node_monitor
        generic map (
            MAX_NODES  => MAX_NODES,
            EMCY_DEPTH => EMCY_DEPTH
        )
        port map (
            clk_i               => clk_i,
            rst_n_i             => rst_n_i,
            tick_ms_i           => tick_ms,
            time_ms_i           => time_ms,
            cfg_node_i          => cfg_node,
            cfg_mode_i          => cfg_mode,
            cfg_autostart_i     => cfg_autostart,
            cfg_reset_on_loss_i => cfg_reset_loss,
            cfg_tl_we_i         => cfg_tl_we,
            cfg_tl_slot_i       => cfg_tl_slot,
            cfg_tl_time_i       => cfg_tl_time,
            cfg_tl_life_i       => cfg_tl_life,
            cfg_tl_ok_i         => cfg_tl_ok,
            st_alive_o          => st_alive,
            st_lost_o           => st_lost,
            st_toggle_o         => st_toggle,
            st_bootup_o         => st_bootup,
            st_rd_slot_i        => node_st_slot,
            st_rd_nmt_i         => node_st_nmt,
            st_rd_data_o        => node_st_data,
            st_clear_i          => node_clear,
            ev_lost_o           => ev_lost,
            ev_toggle_o         => ev_toggle,
            ev_bootup_o         => ev_bootup,
            ev_emcy_o           => ev_emcy,
            emcy_count_o        => emcy_count,
            emcy_lost_o         => emcy_lost,
            emcy_clear_i        => emcy_clear,
            emcy_node_o         => emcy_node,
            emcy_data_o         => emcy_data,
            emcy_time_o         => emcy_time,
            emcy_pop_i          => emcy_pop,
            tx_req_o            => mon_tx_req,
            tx_id_o             => mon_tx_id,
            tx_rtr_o            => mon_tx_rtr,
            tx_dlc_o            => mon_tx_dlc,
            tx_data_o           => mon_tx_data,
            tx_ack_i            => mon_tx_ack,
            rx_valid_i          => enter_nmt,
            rx_id_i             => rx_frame.id,
            rx_rtr_i            => rx_frame.rtr,
            rx_dlc_i            => rx_frame.dlc,
            rx_data_i           => rx_frame.data,
            rx_done_o           => mon_rx_done,
            rx_reply_o          => mon_rx_reply,
            rx_unexpected_o     => mon_rx_unexp,
            rx_malformed_o      => mon_rx_malformed
        );

    pe_sync     <= sync_fire and not omni_en;
    pe_reg_we   <= pdo_reg_we and not omni_en;
    pe_rx_valid <= enter_pdo and not omni_en;
    pe_tx_ack   <= pdo_tx_ack and not omni_en;
    -- the synchronous TPDO withdrawn from TXB0 by a SYNC (not sent: counted late)
    pe_tx_cancelled <= ctl_tx_aborted_i(0) and pdo_cancel_sent;

    pdo_inst : entity work.canopen_pdo_engine
        generic map (
            N_TPDO => N_TPDO,
            N_RPDO => N_RPDO
        )
        port map (
            clk_i           => clk_i,
            rst_n_i         => rst_n_i,
            sync_i          => pe_sync,
            sync_count_i    => sync_sent,
            window_open_i   => window_open,
            tick_us_i       => tick_us,
            reg_addr_i      => pdo_reg_addr,
            reg_we_i        => pe_reg_we,
            reg_wdata_i     => pdo_reg_wdata,
            reg_rdata_o     => pe_reg_rdata,
            rx_valid_i      => pe_rx_valid,
            rx_id_i         => rx_frame.id,
            rx_rtr_i        => rx_frame.rtr,
            rx_dlc_i        => rx_frame.dlc,
            rx_data_i       => rx_frame.data,
            rx_done_o       => pe_rx_done,
            rx_reply_o      => pe_rx_reply,
            rx_unexpected_o => pe_rx_unexp,
            tx_req_o        => pe_tx_req,
            tx_id_o         => pe_tx_id,
            tx_rtr_o        => pe_tx_rtr,
            tx_dlc_o        => pe_tx_dlc,
            tx_data_o       => pe_tx_data,
            tx_ack_i        => pe_tx_ack,
            tx_sync_o       => pe_tx_sync,
            tx_cancelled_i  => pe_tx_cancelled,
            ev_rx_o         => open,
            ev_len_err_o    => open,
            ev_missed_o     => open,
            ev_late_o       => open
        );

    -- ---------------------------------------------------------------------------------------------
    -- Omni-ID engine (CTRL.OMNI): NCTU Omni-ID protocol. It takes the PDO engine's place in St5 and
    -- St8 and in the PDO_WIN window, and gives the SYNC producer its cycle frame (TXB2)
    -- ---------------------------------------------------------------------------------------------
    omni_en <= omni_req when OMNI_ENABLE else
               '0';

    om_cycle    <= sync_fire and omni_en;
    om_reg_we   <= pdo_reg_we and omni_en;
    om_rx_valid <= enter_pdo and omni_en;
    om_tx_ack   <= pdo_tx_ack and omni_en;

    omni_gen : if OMNI_ENABLE generate

        omni_inst : entity work.omni_engine
            generic map (
                BITRATE_BPS => CAN_BITRATE_BPS
            )
            port map (
                clk_i           => clk_i,
                rst_n_i         => rst_n_i,
                enable_i        => omni_en,
                tick_us_i       => tick_us,
                period_us_i     => sync_period_us,
                cycle_i         => om_cycle,
                cyc_id_o        => om_cyc_id,
                cyc_dlc_o       => om_cyc_dlc,
                cyc_data_o      => om_cyc_data,
                cyc_take_i      => om_cyc_take,
                feasible_o      => om_feasible,
                reg_addr_i      => pdo_reg_addr,
                reg_we_i        => om_reg_we,
                reg_wdata_i     => pdo_reg_wdata,
                reg_rdata_o     => om_reg_rdata,
                rx_valid_i      => om_rx_valid,
                rx_id_i         => rx_frame.id,
                rx_rtr_i        => rx_frame.rtr,
                rx_dlc_i        => rx_frame.dlc,
                rx_data_i       => rx_frame.data,
                rx_done_o       => om_rx_done,
                rx_reply_o      => om_rx_reply,
                rx_unexpected_o => om_rx_unexp,
                tx_req_o        => om_tx_req,
                tx_id_o         => om_tx_id,
                tx_rtr_o        => om_tx_rtr,
                tx_dlc_o        => om_tx_dlc,
                tx_data_o       => om_tx_data,
                tx_ack_i        => om_tx_ack,
                ev_o            => om_ev
            );

    end generate omni_gen;

    no_omni_gen : if not OMNI_ENABLE generate

        -- CANopen-only build: CTRL.OMNI has no effect, PDO_WIN always shows the PDO engine
        om_reg_rdata <= (others => '0');
        om_tx_req    <= '0';
        om_tx_id     <= (others => '0');
        om_tx_rtr    <= '0';
        om_tx_dlc    <= (others => '0');
        om_tx_data   <= (others => '0');
        om_rx_done   <= '0';
        om_rx_reply  <= '0';
        om_rx_unexp  <= '0';
        om_cyc_id    <= (others => '0');
        om_cyc_dlc   <= (others => '0');
        om_cyc_data  <= (others => '0');
        om_feasible  <= '0';
        om_ev        <= '0';

    end generate no_omni_gen;

    -- the cycle frame is taken when St11 encapsulates the SYNC-source frame
    om_cyc_take <= sync_encap and omni_en;

    -- the active protocol engine towards the FSM, the datapath and PDO_WIN
    pdo_reg_rdata <= om_reg_rdata when omni_en = '1' else
                     pe_reg_rdata;
    pdo_tx_req    <= om_tx_req when omni_en = '1' else
                     pe_tx_req;
    pdo_tx_id     <= om_tx_id when omni_en = '1' else
                     pe_tx_id;
    pdo_tx_rtr    <= om_tx_rtr when omni_en = '1' else
                     pe_tx_rtr;
    pdo_tx_dlc    <= om_tx_dlc when omni_en = '1' else
                     pe_tx_dlc;
    pdo_tx_data   <= om_tx_data when omni_en = '1' else
                     pe_tx_data;
    pdo_rx_done   <= om_rx_done when omni_en = '1' else
                     pe_rx_done;
    pdo_rx_reply  <= om_rx_reply when omni_en = '1' else
                     pe_rx_reply;
    pdo_rx_unexp  <= om_rx_unexp when omni_en = '1' else
                     pe_rx_unexp;

    -- ---------------------------------------------------------------------------------------------
    -- Automatic configuration: the SDO list run before NMT start (owns the SDO client while busy)
    -- ---------------------------------------------------------------------------------------------

    -- ACFG_CTRL.START waits until a host transfer already running on SDO channel 0 has ended;
    -- from then until the list is finished (acfg_run) channel 0 belongs to the list: host
    -- requests on it are refused (SDO_CMD.REFUSED, its BUSY reads 1) and its done strobes do
    -- not reach the host. The other channels stay the host's. A START while the list runs (or in
    -- Omni-ID mode) is refused: nothing starts, ACFG_STATUS.REFUSED is set.
    acfg_start_proc : process (clk_i, rst_n_i) is
    begin

        if rst_n_i = '0' then
            acfg_start_pend <= '0';
            acfg_refused    <= '0';
        elsif rising_edge(clk_i) then
            -- the pending start is handed to the list (start_i below) when channel 0 is idle
            if acfg_start_pend = '1' and sdo_own_idle = '1' and acfg_busy = '0' then
                acfg_start_pend <= '0';
            end if;
            if acfg_start = '1' then
                if acfg_busy = '0' and acfg_start_pend = '0' and omni_en = '0' then
                    acfg_start_pend <= '1';
                    acfg_refused    <= '0';
                else
                    acfg_refused <= '1';
                end if;
            end if;
        end if;

    end process acfg_start_proc;

    acfg_run <= acfg_busy or acfg_start_pend;

    -- ACFG_STATUS.REFUSED as the host reads it: the decision already in the cycle of the START
    acfg_ref_view <= (acfg_busy or acfg_start_pend or omni_en) when acfg_start = '1' else
                     acfg_refused;

    acfg_go        <= acfg_start_pend and sdo_own_idle and not acfg_busy;
    acfg_nmt_ready <= not acfg_nmt_pending;

    acfg_inst : entity work.canopen_autoconfig
        generic map (
            CFG_DEPTH => CFG_DEPTH
        )
        port map (
            clk_i           => clk_i,
            rst_n_i         => rst_n_i,
            tbl_we_i        => acfg_tbl_we,
            tbl_addr_i      => acfg_tbl_addr,
            tbl_node_i      => acfg_tbl_node,
            tbl_index_i     => acfg_tbl_index,
            tbl_sub_i       => acfg_tbl_sub,
            tbl_size_i      => acfg_tbl_size,
            tbl_value_i     => acfg_tbl_value,
            start_i         => acfg_go,
            start_nodes_i   => acfg_start_nodes,
            busy_o          => acfg_busy,
            done_o          => acfg_done,
            nodes_ok_o      => acfg_nodes_ok,
            nodes_fail_o    => acfg_nodes_fail,
            log_sel_i       => acfg_fail_sel,
            fail_node_o     => acfg_fail_node,
            fail_entry_o    => acfg_fail_entry,
            fail_abort_o    => acfg_fail_abort,
            ev_fail_o       => open,
            sdo_req_o       => acfg_sdo_req,
            sdo_node_o      => acfg_sdo_node,
            sdo_index_o     => acfg_sdo_index,
            sdo_sub_o       => acfg_sdo_sub,
            sdo_size_o      => acfg_sdo_size,
            sdo_buf_we_o    => acfg_buf_we,
            sdo_buf_wdata_o => acfg_buf_wdata,
            sdo_done_i      => sdo_own_done,
            sdo_error_i     => sdo_own_error,
            sdo_abort_i     => sdo_own_abort,
            nmt_req_o       => acfg_nmt_req,
            nmt_node_o      => acfg_nmt_node,
            nmt_ready_i     => acfg_nmt_ready
        );

    -- ---------------------------------------------------------------------------------------------
    -- Host registers
    -- ---------------------------------------------------------------------------------------------
    can_err_passive <= can_eflg(4) or can_eflg(3);
    host_ev_node    <= ev_node_any or om_ev;

    regs_inst : entity work.canopen_host_regs
        generic map (
            MAX_NODES => MAX_NODES,
            N_SDO     => N_SDO
        )
        port map (
            clk_i                    => clk_i,
            rst_n_i                  => rst_n_i,
            avs_address_i            => avs_address_i,
            avs_read_i               => avs_read_i,
            avs_write_i              => avs_write_i,
            avs_writedata_i          => avs_writedata_i,
            avs_byteenable_i         => avs_byteenable_i,
            avs_readdata_o           => avs_readdata_o,
            avs_readdatavalid_o      => avs_readdatavalid_o,
            irq_o                    => irq_o,
            sync_en_o                => sync_en,
            omni_en_o                => omni_req,
            reinit_o                 => host_reinit,
            nmt_req_o                => nmt_req,
            nmt_cs_o                 => nmt_cs,
            nmt_node_o               => nmt_node,
            sync_period_us_o         => sync_period_us,
            sync_overflow_o          => sync_overflow,
            sync_window_us_o         => sync_window_us,
            node_cfg_node_o          => cfg_node,
            node_cfg_mode_o          => cfg_mode,
            node_cfg_autostart_o     => cfg_autostart,
            node_cfg_reset_on_loss_o => cfg_reset_loss,
            node_clear_o             => node_clear,
            node_tl_we_o             => cfg_tl_we,
            node_tl_slot_o           => cfg_tl_slot,
            node_tl_time_o           => cfg_tl_time,
            node_tl_life_o           => cfg_tl_life,
            node_tl_ok_o             => cfg_tl_ok,
            emcy_clear_o             => emcy_clear,
            emcy_pop_o               => emcy_pop,
            sdo_req_o                => sdo_req,
            sdo_upload_o             => sdo_upload,
            sdo_node_o               => sdo_node,
            sdo_index_o              => sdo_index,
            sdo_subindex_o           => sdo_subindex,
            sdo_size_o               => sdo_size,
            sdo_timeout_ms_o         => sdo_timeout_ms,
            sdo_cob_req_o            => sdo_cob_req,
            sdo_cob_resp_o           => sdo_cob_resp,
            sdo_chan_o               => sdo_chan,
            sdo_buf_addr_o           => sdo_buf_addr,
            sdo_buf_we_o             => sdo_buf_we,
            sdo_buf_wdata_o          => sdo_buf_wdata,
            pdo_addr_o               => pdo_reg_addr,
            pdo_we_o                 => pdo_reg_we,
            pdo_wdata_o              => pdo_reg_wdata,
            pdo_rdata_i              => pdo_reg_rdata,
            acfg_start_o             => acfg_start,
            acfg_start_nodes_o       => acfg_start_nodes,
            acfg_tbl_we_o            => acfg_tbl_we,
            acfg_tbl_addr_o          => acfg_tbl_addr,
            acfg_tbl_node_o          => acfg_tbl_node,
            acfg_tbl_index_o         => acfg_tbl_index,
            acfg_tbl_sub_o           => acfg_tbl_sub,
            acfg_tbl_size_o          => acfg_tbl_size,
            acfg_tbl_value_o         => acfg_tbl_value,
            fsm_state_i              => fsm_state,
            init_done_i              => ctl_init_done_i,
            init_fail_i              => ctl_init_fail_i,
            ctrl_busy_i              => ctl_busy_i,
            tx_pending_i             => ctl_tx_pending_i,
            bus_off_i                => can_eflg(MCP_EFLG_TXBO_BIT_C),
            err_passive_i            => can_err_passive,
            nmt_busy_i               => nmt_pending,
            nmt_refused_i            => nmt_ref_view,
            sync_count_i             => sync_count,
            time_us_i                => time_us,
            tec_i                    => can_tec,
            rec_i                    => can_rec,
            eflg_i                   => can_eflg,
            node_alive_i             => st_alive,
            node_lost_i              => st_lost,
            node_toggle_i            => st_toggle,
            node_bootup_i            => st_bootup,
            node_st_slot_o           => node_st_slot,
            node_st_nmt_o            => node_st_nmt,
            node_st_data_i           => node_st_data,
            emcy_count_i             => emcy_count,
            emcy_lost_i              => emcy_lost,
            emcy_node_i              => emcy_node_h,
            emcy_data_i              => emcy_data_h,
            emcy_time_i              => emcy_time_h,
            sdo_busy_i               => sdo_busy,
            sdo_error_i              => sdo_error,
            sdo_abort_code_i         => sdo_abort_code,
            sdo_abort_sent_i         => sdo_abort_sent,
            sdo_size_i               => sdo_xfer_size,
            sdo_refused_i            => sdo_refused,
            sdo_start_i              => sdo_ch_go,
            sdo_chan_busy_i          => sdo_ch_busy,
            sdo_buf_rdata_i          => sdo_buf_rdata,
            acfg_busy_i              => acfg_run,
            acfg_refused_i           => acfg_ref_view,
            acfg_nodes_ok_i          => acfg_nodes_ok,
            acfg_nodes_fail_i        => acfg_nodes_fail,
            acfg_fail_node_i         => acfg_fail_node,
            acfg_fail_entry_i        => acfg_fail_entry,
            acfg_fail_abort_i        => acfg_fail_abort,
            acfg_fail_sel_o          => acfg_fail_sel,
            ev_node_i                => host_ev_node,
            ev_emcy_i                => ev_emcy,
            ev_sdo_done_i            => sdo_ch_done,
            ev_can_error_i           => ev_can_error,
            ev_sync_i                => sync_fire,
            ev_frame_error_i         => ev_frame_error,
            ev_init_i                => ev_init,
            ev_acfg_done_i           => acfg_done,
            cnt_rx_frame_i           => cnt_rx_frame,
            cnt_tx_frame_i           => cnt_tx_frame,
            cnt_unexpected_i         => cnt_unexpected,
            cnt_malformed_i          => cnt_malformed,
            cnt_rx_overflow_i        => ctl_rx_overflow_i,
            cnt_tx_error_i           => cnt_tx_error,
            cnt_sdo_abort_i          => sdo_cnt_abort,
            cnt_hb_loss_i            => cnt_hb_loss,
            cnt_guard_err_i          => cnt_guard_err,
            cnt_can_error_i          => cnt_can_error,
            cnt_emcy_i               => ev_emcy
        );

end architecture rtl;
