-- =================================================================================================
-- Title    : canopen_host_regs
-- Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
-- SPDX-License-Identifier: Apache-2.0
-- =================================================================================================
-- Module:
--   Host register block: Avalon-MM slave (32-bit data, word addresses, registered inputs,
--   fixed read latency 2, no waitrequest) and level-high interrupt sender.
-- Purpose:
--   The software view of the CANopen master (map: docs/register_map.md, generated with
--   canopen_regs_pkg by scripts/regmap.py). It holds the configuration registers (SYNC, node
--   supervision slots, SDO channel select, object and timeout), the interrupt flags and
--   enables, and eleven 32-bit saturating event counters; it turns writes into one-cycle
--   command strobes (NMT, SDO start, re-init, clear, EMCY pop) with their fields, shows the
--   status inputs of the other blocks, and passes the SDO_BUF window through to the buffer RAM
--   of the selected SDO channel and the PDO_WIN window (C0h..FFh) to the PDO engine's register
--   port. SDO_CMD.DONE is kept per channel (set by that channel's done event, cleared when the
--   channel accepts the next SDO_CMD write: sdo_start_i; a refused write leaves it).
--   * Input validation: SYNC_OVERFLOW takes 0 or 2..240 only, and no other value while the
--     SYNC producer runs (CiA 301 1019h); a refused write keeps the value and sets
--     SYNC_OVERFLOW.REFUSED until the next accepted write. NMT and SDO commands are checked
--     where they are executed (canopen_master_core, canopen_sdo_channels).
--   * Avalon inputs: address, read, write, writedata and byteenable are registered at the
--     port (av_*); everything below works on the registered request, one cycle after the bus
--     cycle (writes act then, in order with the reads). Address bits 6..0 also go to the RW
--     word RAM's address register (sampled at the same edge), see below.
--   * Reads: the whole read multiplexer is registered, so readdata/readdatavalid follow
--     avs_read_i by exactly two cycles for every address. SDO_BUF reads drive sdo_buf_addr_o
--     in the registered read cycle; the RAM's registered data (sdo_buf_rdata_i) is selected in
--     the next one. PDO_WIN reads likewise: pdo_addr_o, then pdo_rdata_i selected.
--   * RW word RAM: the RW registers without side effects or checks (IRQ_ENABLE, SYNC period
--     and window, SDO object / timeout / COB-IDs, ACFG_OBJ, ACFG_FAIL_SEL, NODE_CFG(k),
--     NODE_TIME(k)) are read back from one RAM, not through the read multiplexer: the word's
--     old value (the previous cycle's write to it, the RAM's word, or the reset value for a
--     word not written since reset) is read in the act cycle and merged with a partial write.
--     Their flip-flops stay where a block uses the value; NODE_TIME(k) exists only in RAMs
--     (node_tl_*: passed on to the node monitor's copy one cycle after the act cycle).
--   * RW registers merge a partial write with their own value (per bit: the byte enable
--     chooses, which synthesis maps to the flip-flop enable), not with the read multiplexer.
--   * Byte enables: honoured by RW registers (only enabled bytes change) and by W1C/pulse bits
--     (bits in disabled bytes count as 0). Command registers (NMT_CMD, SDO_CMD, EMCY_POP) act
--     on any write and take every field from avs_writedata_i. The SDO_BUF port has no byte
--     lanes: a window write with avs_byteenable_i /= "1111" is ignored (PDO_WIN: the same).
--   * IRQ_STATUS: event strobes set the flags, writing 1 clears them; a flag set and cleared in
--     the same cycle stays set (no event is lost). irq_o = OR(IRQ_STATUS and IRQ_ENABLE).
--   * Counters: incremented by the cnt_*_i strobes (cnt_rx_overflow_i by its number of set
--     bits), stop at FFFFFFFFh; CTRL.CLR_COUNTERS clears them (a clear wins over a strobe in
--     the same cycle, a read after the clear returns 0). They live in a canopen_counter_bank
--     (block RAM, one shared incrementer, a strobe in every cycle is counted): a CNT_* read
--     drives the bank's read address in the read cycle and selects its registered data in the
--     next one, like SDO_BUF; the count it returns may lag the strobes by at most 13 cycles
--     (docs/canopen_counter_bank.md). CNT_BITS < 32 narrows them (saturating at
--     2**CNT_BITS - 1, read zero-extended) so that a bench can reach saturation; the register
--     map says 32.
-- =================================================================================================

library ieee;
    use ieee.std_logic_1164.all;
    use ieee.numeric_std.all;

library work;
    use work.canopen_regs_pkg.all;
    use work.canopen_util_pkg.all;

entity canopen_host_regs is
    generic (
        MAX_NODES : positive range 1 to 16 := 8; -- supervised node slots (registers per slot)
        N_SDO     : positive range 1 to 4  := 2; -- SDO client channels (SDO_SEL.CHAN range)
        CNT_BITS  : positive range 2 to 32 := 32 -- event counter width; < 32 only for benches
    );
    port (
        -- clock and reset
        clk_i   : in    std_logic; -- system clock
        rst_n_i : in    std_logic; -- async reset, active low
        -- Avalon-MM slave
        avs_address_i       : in    std_logic_vector(7 downto 0);  -- word address
        avs_read_i          : in    std_logic;                     -- read request
        avs_write_i         : in    std_logic;                     -- write request
        avs_writedata_i     : in    std_logic_vector(31 downto 0); -- write data
        avs_byteenable_i    : in    std_logic_vector(3 downto 0);  -- byte lanes of a write
        avs_readdata_o      : out   std_logic_vector(31 downto 0); -- read data
        avs_readdatavalid_o : out   std_logic;                     -- read data valid (+1 cycle)
        -- interrupt sender
        irq_o : out   std_logic; -- level high: OR(IRQ_STATUS and IRQ_ENABLE)
        -- master control and SYNC configuration
        sync_en_o        : out   std_logic;                     -- CTRL.SYNC_EN
        omni_en_o        : out   std_logic;                     -- CTRL.OMNI: Omni-ID mode
        reinit_o         : out   std_logic;                     -- pulse: CTRL.REINIT
        nmt_req_o        : out   std_logic;                     -- pulse: NMT_CMD written
        nmt_cs_o         : out   std_logic_vector(7 downto 0);  -- NMT command specifier
        nmt_node_o       : out   std_logic_vector(7 downto 0);  -- NMT node-ID, 0 = all, > 127 bad
        sync_period_us_o : out   std_logic_vector(31 downto 0); -- SYNC period [us], 0 = off
        sync_overflow_o  : out   std_logic_vector(7 downto 0);  -- SYNC counter overflow
        sync_window_us_o : out   std_logic_vector(31 downto 0); -- synchronous window [us]
        -- node supervision configuration, slot k in bits (k+1)*w-1 .. k*w
        node_cfg_node_o          : out   std_logic_vector(7 * MAX_NODES - 1 downto 0); -- id
        node_cfg_mode_o          : out   std_logic_vector(2 * MAX_NODES - 1 downto 0); -- mode
        node_cfg_autostart_o     : out   std_logic_vector(MAX_NODES - 1 downto 0);     -- flag
        node_cfg_reset_on_loss_o : out   std_logic_vector(MAX_NODES - 1 downto 0);     -- flag
        node_clear_o             : out   std_logic_vector(MAX_NODES - 1 downto 0);     -- pulse
        -- NODE_TIME write port (the node monitor keeps its own copy in RAM): the slot's whole
        -- new word in the cycle it is written, and the slots written since reset (others are 0)
        node_tl_we_o   : out   std_logic;                                -- pulse: written
        node_tl_slot_o : out   std_logic_vector(4 downto 0);             -- slot
        node_tl_time_o : out   std_logic_vector(15 downto 0);            -- TIME_MS [ms]
        node_tl_life_o : out   std_logic_vector(7 downto 0);             -- LIFE_FACTOR
        node_tl_ok_o   : out   std_logic_vector(MAX_NODES - 1 downto 0); -- written since reset
        -- EMCY FIFO control
        emcy_clear_o : out   std_logic; -- pulse: clear the EMCY lost flag
        emcy_pop_o   : out   std_logic; -- pulse: drop the EMCY FIFO head
        -- SDO client request
        sdo_req_o        : out   std_logic;                     -- pulse: start a transfer
        sdo_upload_o     : out   std_logic;                     -- 1 upload, 0 download
        sdo_node_o       : out   std_logic_vector(7 downto 0);  -- server node-ID (0, > 127 bad)
        sdo_index_o      : out   std_logic_vector(15 downto 0); -- object index
        sdo_subindex_o   : out   std_logic_vector(7 downto 0);  -- object sub-index
        sdo_size_o       : out   std_logic_vector(10 downto 0); -- download size [bytes]
        sdo_timeout_ms_o : out   std_logic_vector(15 downto 0); -- response timeout [ms]
        sdo_cob_req_o    : out   std_logic_vector(10 downto 0); -- request COB-ID, 0 = default
        sdo_cob_resp_o   : out   std_logic_vector(10 downto 0); -- response COB-ID, 0 = default
        sdo_chan_o       : out   std_logic_vector(1 downto 0);  -- SDO_SEL.CHAN
        -- SDO client buffer port (RAM with registered read data)
        sdo_buf_addr_o  : out   std_logic_vector(7 downto 0);  -- word address
        sdo_buf_we_o    : out   std_logic;                     -- write enable
        sdo_buf_wdata_o : out   std_logic_vector(31 downto 0); -- write data
        sdo_buf_rdata_i : in    std_logic_vector(31 downto 0); -- read data (+1 cycle)
        -- PDO engine register port (registered read data)
        pdo_addr_o  : out   std_logic_vector(5 downto 0);  -- word offset in PDO_WIN
        pdo_we_o    : out   std_logic;                     -- write enable
        pdo_wdata_o : out   std_logic_vector(31 downto 0); -- write data
        -- vsg_off port_012: default 0 keeps instances without the PDO engine elaborating
        pdo_rdata_i : in    std_logic_vector(31 downto 0) := (others => '0'); -- read (+1)
        -- vsg_on port_012
        -- automatic configuration (canopen_autoconfig): control and table write port
        acfg_start_o       : out   std_logic;                     -- pulse: ACFG_CTRL.START
        acfg_start_nodes_o : out   std_logic;                     -- ACFG_CTRL.START_NODES
        acfg_tbl_we_o      : out   std_logic;                     -- pulse: ACFG_VALUE written
        acfg_tbl_addr_o    : out   std_logic_vector(7 downto 0);  -- entry number
        acfg_tbl_node_o    : out   std_logic_vector(6 downto 0);  -- entry node-ID
        acfg_tbl_index_o   : out   std_logic_vector(15 downto 0); -- entry index
        acfg_tbl_sub_o     : out   std_logic_vector(7 downto 0);  -- entry sub-index
        acfg_tbl_size_o    : out   std_logic_vector(2 downto 0);  -- entry size 1..4
        acfg_tbl_value_o   : out   std_logic_vector(31 downto 0); -- entry value
        -- master and CAN controller status
        fsm_state_i   : in    std_logic_vector(3 downto 0);  -- master FSM state
        init_done_i   : in    std_logic;                     -- CAN controller running
        init_fail_i   : in    std_logic;                     -- CAN controller init failed
        ctrl_busy_i   : in    std_logic;                     -- CAN controller busy
        tx_pending_i  : in    std_logic_vector(2 downto 0);  -- TX buffers pending
        bus_off_i     : in    std_logic;                     -- bus-off
        err_passive_i : in    std_logic;                     -- error passive
        nmt_busy_i    : in    std_logic;                     -- NMT command being sent
        nmt_refused_i : in    std_logic;                     -- sticky: NMT_CMD write refused
        sync_count_i  : in    std_logic_vector(31 downto 0); -- SYNC frames sent
        time_us_i     : in    std_logic_vector(31 downto 0); -- free-running us counter
        tec_i         : in    std_logic_vector(7 downto 0);  -- transmit error counter
        rec_i         : in    std_logic_vector(7 downto 0);  -- receive error counter
        eflg_i        : in    std_logic_vector(7 downto 0);  -- MCP2510 EFLG
        -- node supervision status, slot k in bits (k+1)*w-1 .. k*w
        node_alive_i  : in    std_logic_vector(MAX_NODES - 1 downto 0); -- alive
        node_lost_i   : in    std_logic_vector(MAX_NODES - 1 downto 0); -- sticky: lost
        node_toggle_i : in    std_logic_vector(MAX_NODES - 1 downto 0); -- sticky: toggle
        node_bootup_i : in    std_logic_vector(MAX_NODES - 1 downto 0); -- sticky: boot-up
        -- node status RAM of canopen_node_monitor: slot to read, its data one cycle later
        node_st_slot_o : out   std_logic_vector(4 downto 0);  -- slot of NODE_STATUS/LAST_MS
        node_st_nmt_o  : out   std_logic;                     -- 1: its NMT state, 0: its time
        node_st_data_i : in    std_logic_vector(31 downto 0); -- state (6..0) or time (+1 cycle)
        -- EMCY FIFO status (head)
        emcy_count_i : in    std_logic_vector(6 downto 0);  -- messages in the FIFO
        emcy_lost_i  : in    std_logic;                     -- sticky: a message was lost
        emcy_node_i  : in    std_logic_vector(6 downto 0);  -- head: node-ID
        emcy_data_i  : in    std_logic_vector(63 downto 0); -- head: bytes 0..7
        emcy_time_i  : in    std_logic_vector(31 downto 0); -- head: time [ms]
        -- SDO client status
        sdo_busy_i       : in    std_logic;                     -- transfer running
        sdo_error_i      : in    std_logic;                     -- last transfer aborted
        sdo_abort_code_i : in    std_logic_vector(31 downto 0); -- abort code (+1 cycle)
        sdo_abort_sent_i : in    std_logic;                     -- 1: client aborted (+1)
        sdo_size_i       : in    std_logic_vector(10 downto 0); -- bytes transferred (+1)
        sdo_refused_i    : in    std_logic;                     -- the last request was refused
        sdo_start_i      : in    std_logic_vector(3 downto 0);  -- request accepted, per channel
        sdo_chan_busy_i  : in    std_logic_vector(3 downto 0);  -- busy, per channel
        -- automatic configuration status
        acfg_busy_i       : in    std_logic;                     -- list running
        acfg_refused_i    : in    std_logic;                     -- sticky: START refused
        acfg_nodes_ok_i   : in    std_logic_vector(7 downto 0);  -- nodes configured
        acfg_nodes_fail_i : in    std_logic_vector(7 downto 0);  -- nodes failed
        acfg_fail_node_i  : in    std_logic_vector(6 downto 0);  -- selected failure: node
        acfg_fail_entry_i : in    std_logic_vector(7 downto 0);  -- selected failure: entry
        acfg_fail_abort_i : in    std_logic_vector(31 downto 0); -- failure: abort code
        acfg_fail_sel_o   : out   std_logic_vector(3 downto 0);  -- ACFG_FAIL_SEL.INDEX
        -- interrupt events (one-cycle strobes)
        ev_node_i        : in    std_logic;                    -- node event
        ev_emcy_i        : in    std_logic;                    -- EMCY received
        ev_sdo_done_i    : in    std_logic_vector(3 downto 0); -- SDO channel c finished
        ev_can_error_i   : in    std_logic;                    -- CAN controller error
        ev_sync_i        : in    std_logic;                    -- SYNC sent
        ev_frame_error_i : in    std_logic;                    -- unexpected or malformed frame
        ev_init_i        : in    std_logic;                    -- initialisation done or failed
        ev_acfg_done_i   : in    std_logic;                    -- configuration list finished
        -- counter increments (one-cycle strobes)
        cnt_rx_frame_i    : in    std_logic;                    -- frame received
        cnt_tx_frame_i    : in    std_logic;                    -- frame sent
        cnt_unexpected_i  : in    std_logic;                    -- unexpected frame
        cnt_malformed_i   : in    std_logic;                    -- malformed frame
        cnt_rx_overflow_i : in    std_logic_vector(1 downto 0); -- frames lost (RXnOVR)
        cnt_tx_error_i    : in    std_logic;                    -- transmit error
        cnt_sdo_abort_i   : in    std_logic;                    -- SDO abort
        cnt_hb_loss_i     : in    std_logic;                    -- heartbeat lost
        cnt_guard_err_i   : in    std_logic;                    -- guarding error
        cnt_can_error_i   : in    std_logic;                    -- CAN error interrupt
        cnt_emcy_i        : in    std_logic                     -- EMCY received
    );
end entity canopen_host_regs;

architecture rtl of canopen_host_regs is

    -- ---------------------------------------------------------------------------------------------
    -- Elaboration-time configuration
    -- ---------------------------------------------------------------------------------------------

    -- counters in address order, CNT_RX_FRAMES .. CNT_EMCY
    constant cnt_num_c  : positive := REG_CNT_EMCY_C - REG_CNT_RX_FRAMES_C + 1;
    constant irq_bits_c : positive := IRQ_STATUS_CONFIG_C + 1;
    -- SDO_BUF window: low address bits select the word, high bits the window
    constant buf_bits_c : natural := clog2(REG_SDO_BUF_WORDS_C);
    constant buf_win_c  : natural := REG_SDO_BUF_C / REG_SDO_BUF_WORDS_C;
    -- PDO_WIN window, decoded the same way
    constant pdo_bits_c : natural := clog2(REG_PDO_WIN_WORDS_C);
    constant pdo_win_c  : natural := REG_PDO_WIN_C / REG_PDO_WIN_WORDS_C;
    -- NODE_TIME: bits 23..0 of the register (TIME_MS, LIFE_FACTOR)
    constant tl_bits_c : positive := NODE_TIME_LIFE_FACTOR_HI_C + 1;

    -- RW word RAM: the RW registers without side effects or checks, read back from a block
    -- RAM instead of the read multiplexer (their flip-flops stay where a block uses the value):
    -- the fixed words below, NODE_CFG(k) and NODE_TIME(k) of each slot. The RAM's address is
    -- the register address (bits 6..0): no decode before it.

    type addr_list_t is array (natural range <>) of natural;

    constant rw_fixed_c : addr_list_t(0 to 7) :=
    (
        REG_IRQ_ENABLE_C,
        REG_SYNC_PERIOD_US_C,
        REG_SYNC_WINDOW_US_C,
        REG_SDO_OBJ_C,
        REG_SDO_TIMEOUT_MS_C,
        REG_SDO_COB_C,
        REG_ACFG_OBJ_C,
        REG_ACFG_FAIL_SEL_C
    );
    constant rw_depth_c : positive            := 128;

    function check_config return boolean is
    begin

        assert MAX_NODES <= REG_NODE_SLOTS_MAX_C
            report "canopen_host_regs: MAX_NODES = " & integer'image(MAX_NODES)
                   & " above the register map's " & integer'image(REG_NODE_SLOTS_MAX_C)
                   & " node slots"
            severity failure;
        assert NODE_TIME_TIME_MS_LO_C = 0 and NODE_TIME_TIME_MS_HI_C = 15
               and NODE_TIME_LIFE_FACTOR_LO_C = 16 and NODE_TIME_LIFE_FACTOR_HI_C = 23
            report "canopen_host_regs: NODE_TIME is not TIME_MS 15..0, LIFE_FACTOR 23..16"
            severity failure;
        assert REG_NODE_TIME_C = REG_NODE_CFG_C + 1 and REG_NODE_STRIDE_C = 4
               and REG_NODE_CFG_C mod 4 = 0
               and REG_NODE_CFG_C + REG_NODE_SLOTS_MAX_C * REG_NODE_STRIDE_C <= rw_depth_c
            report "canopen_host_regs: NODE_CFG / NODE_TIME are not words 0 / 1 of 4-word slots "
                   & "below word 128"
            severity failure;

        for i in rw_fixed_c'range loop

            assert rw_fixed_c(i) < rw_depth_c
                report "canopen_host_regs: an RW word of the RW word RAM at or above word 128"
                severity failure;

        end loop;

        assert NODE_STATUS_NMT_STATE_LO_C = 0 and NODE_STATUS_NMT_STATE_HI_C = 6
            report "canopen_host_regs: NODE_STATUS.NMT_STATE is not bits 6..0 (the status RAM's "
                   & "word)"
            severity failure;
        assert cnt_num_c = 11
            report "canopen_host_regs: CNT_RX_FRAMES .. CNT_EMCY are not 11 consecutive words"
            severity failure;
        assert 2 ** buf_bits_c = REG_SDO_BUF_WORDS_C and REG_SDO_BUF_C mod REG_SDO_BUF_WORDS_C = 0
            report "canopen_host_regs: SDO_BUF window not a power of two aligned to its size"
            severity failure;
        assert 2 ** pdo_bits_c = REG_PDO_WIN_WORDS_C and pdo_bits_c = 6
               and REG_PDO_WIN_C mod REG_PDO_WIN_WORDS_C = 0
            report "canopen_host_regs: PDO_WIN window is not 64 words aligned to its size"
            severity failure;
        report "canopen_host_regs: MAX_NODES = " & integer'image(MAX_NODES)
               & ", CNT_BITS = " & integer'image(CNT_BITS)
               & ", node registers at word " & integer'image(REG_NODE_CFG_C) & " .. "
               & integer'image(REG_NODE_CFG_C + MAX_NODES * REG_NODE_STRIDE_C - 1)
            severity note;
        return true;

    end function check_config;

    constant config_ok_c : boolean := check_config;

    -- ---------------------------------------------------------------------------------------------
    -- Helpers
    -- ---------------------------------------------------------------------------------------------

    -- a SYNC_OVERFLOW write is accepted: 0 or 2..240 (CiA 301 1019h), and while the SYNC
    -- producer runs only the value it already has

    function sync_ovf_ok (v : std_logic_vector(7 downto 0); cur : std_logic_vector(7 downto 0);
        running : boolean) return boolean is
    begin

        if unsigned(v) = 1 or unsigned(v) > 240 then
            return false;
        end if;

        return not running or v = cur;

    end function sync_ovf_ok;

    -- a configuration list entry is accepted: the end marker (node 0), or node 1..127 with a
    -- value of 1..4 bytes (expedited download)

    function acfg_entry_ok (node : std_logic_vector(7 downto 0);
        size : std_logic_vector(2 downto 0)) return boolean is
    begin

        if unsigned(node) = 0 then
            return true;
        end if;

        return node(7) = '0' and unsigned(size) >= 1 and unsigned(size) <= 4;

    end function acfg_entry_ok;

    -- the node slot of a per-node register address (slot 0 outside the node registers and for
    -- slots >= MAX_NODES: callers qualify it with the address decode)

    function slot_of (addr : std_logic_vector(7 downto 0)) return natural is

        variable off_v : unsigned(7 downto 0);

    begin

        off_v := unsigned(addr) - REG_NODE_CFG_C;

        if to_integer(off_v(5 downto 2)) < MAX_NODES then
            return to_integer(off_v(5 downto 2));
        end if;

        return 0;

    end function slot_of;

    -- the register's fields (the bits a write stores; the others read 0)

    function ones (hi, lo : natural) return std_logic_vector is
    begin

        return at((hi - lo downto 0 => '1'), hi, lo);

    end function ones;

    function rw_mask (addr : std_logic_vector(7 downto 0)) return std_logic_vector is
    begin

        if is_off(addr, REG_IRQ_ENABLE_C) then
            return ones(irq_bits_c - 1, 0);
        elsif is_off(addr, REG_SYNC_PERIOD_US_C) then
            return ones(SYNC_PERIOD_US_VALUE_HI_C, SYNC_PERIOD_US_VALUE_LO_C);
        elsif is_off(addr, REG_SYNC_WINDOW_US_C) then
            return ones(SYNC_WINDOW_US_VALUE_HI_C, SYNC_WINDOW_US_VALUE_LO_C);
        elsif is_off(addr, REG_SDO_OBJ_C) then
            return ones(SDO_OBJ_INDEX_HI_C, SDO_OBJ_INDEX_LO_C)
                   or ones(SDO_OBJ_SUBINDEX_HI_C, SDO_OBJ_SUBINDEX_LO_C);
        elsif is_off(addr, REG_SDO_TIMEOUT_MS_C) then
            return ones(SDO_TIMEOUT_MS_VALUE_HI_C, SDO_TIMEOUT_MS_VALUE_LO_C);
        elsif is_off(addr, REG_SDO_COB_C) then
            return ones(SDO_COB_REQUEST_HI_C, SDO_COB_REQUEST_LO_C)
                   or ones(SDO_COB_RESPONSE_HI_C, SDO_COB_RESPONSE_LO_C);
        elsif is_off(addr, REG_ACFG_OBJ_C) then
            return ones(ACFG_OBJ_INDEX_HI_C, ACFG_OBJ_INDEX_LO_C)
                   or ones(ACFG_OBJ_SUBINDEX_HI_C, ACFG_OBJ_SUBINDEX_LO_C);
        elsif is_off(addr, REG_ACFG_FAIL_SEL_C) then
            return ones(ACFG_FAIL_SEL_INDEX_HI_C, ACFG_FAIL_SEL_INDEX_LO_C);
        end if;

        if addr(0) = '0' then
            return ones(NODE_CFG_NODE_ID_HI_C, NODE_CFG_NODE_ID_LO_C)
                   or ones(NODE_CFG_MODE_HI_C, NODE_CFG_MODE_LO_C)
                   or at('1', NODE_CFG_AUTOSTART_C) or at('1', NODE_CFG_RESET_ON_LOSS_C);
        end if;

        return ones(tl_bits_c - 1, 0);

    end function rw_mask;

    -- its value after reset (the register map's reset value)

    function rw_reset (addr : std_logic_vector(7 downto 0)) return std_logic_vector is
    begin

        if is_off(addr, REG_IRQ_ENABLE_C) then
            return IRQ_ENABLE_RESET_C;
        elsif is_off(addr, REG_SYNC_PERIOD_US_C) then
            return SYNC_PERIOD_US_RESET_C;
        elsif is_off(addr, REG_SYNC_WINDOW_US_C) then
            return SYNC_WINDOW_US_RESET_C;
        elsif is_off(addr, REG_SDO_OBJ_C) then
            return SDO_OBJ_RESET_C;
        elsif is_off(addr, REG_SDO_TIMEOUT_MS_C) then
            return SDO_TIMEOUT_MS_RESET_C;
        elsif is_off(addr, REG_SDO_COB_C) then
            return SDO_COB_RESET_C;
        elsif is_off(addr, REG_ACFG_OBJ_C) then
            return ACFG_OBJ_RESET_C;
        elsif is_off(addr, REG_ACFG_FAIL_SEL_C) then
            return ACFG_FAIL_SEL_RESET_C;
        elsif addr(0) = '0' then
            return NODE_CFG_RESET_C;
        end if;

        return NODE_TIME_RESET_C;

    end function rw_reset;

    -- a write into the field hi..lo of an RW register: the enabled bytes from the write data,
    -- the others from the register itself (not through the read multiplexer)

    function mrg (old : std_logic_vector; wd, be : std_logic_vector(31 downto 0);
        hi, lo : natural) return std_logic_vector is

        variable r : std_logic_vector(hi - lo downto 0);
        variable o : std_logic_vector(hi - lo downto 0);

    begin

        o := old;

        -- a 2:1 choice per bit (not AND-OR): synthesis turns it into the flip-flop's enable
        for i in 0 to hi - lo loop

            if be(lo + i) = '1' then
                r(i) := wd(lo + i);
            else
                r(i) := o(i);
            end if;

        end loop;

        return r;

    end function mrg;

    function mrg_bit (old : std_logic; wd, be : std_logic_vector(31 downto 0);
        pos : natural) return std_logic is
    begin

        if be(pos) = '1' then
            return wd(pos);
        end if;

        return old;

    end function mrg_bit;

    -- ---------------------------------------------------------------------------------------------
    -- Signals
    -- ---------------------------------------------------------------------------------------------

    -- the Avalon request, registered at the port: address, read, write, data, byte enables
    signal av_addr : std_logic_vector(7 downto 0);
    signal av_rd   : std_logic;
    signal av_wr   : std_logic;
    signal av_wd   : std_logic_vector(31 downto 0);
    signal av_be   : std_logic_vector(3 downto 0);

    -- byte enables expanded to bits
    signal be_bits : std_logic_vector(31 downto 0);
    -- W1C and pulse bits: the write data with disabled bytes forced to 0
    signal wr_ones : std_logic_vector(31 downto 0);
    -- the bus address is inside the SDO_BUF window
    signal buf_sel : std_logic;
    -- the bus address is inside the PDO_WIN window
    signal pdo_sel : std_logic;

    -- node slot registers

    type slot_id_t is array (0 to MAX_NODES - 1) of std_logic_vector(6 downto 0);

    type slot_mode_t is array (0 to MAX_NODES - 1) of std_logic_vector(1 downto 0);

    -- RW registers
    signal sync_en       : std_logic;
    signal omni_en       : std_logic;
    signal irq_enable    : std_logic_vector(irq_bits_c - 1 downto 0);
    signal sync_period   : std_logic_vector(31 downto 0);
    signal sync_overflow : std_logic_vector(7 downto 0);
    -- the last SYNC_OVERFLOW write was refused (reserved value, or a change while SYNC runs)
    signal ovf_refused    : std_logic;
    signal sync_window    : std_logic_vector(31 downto 0);
    signal node_id        : slot_id_t;
    signal node_mode      : slot_mode_t;
    signal node_autostart : std_logic_vector(MAX_NODES - 1 downto 0);
    signal node_rst_loss  : std_logic_vector(MAX_NODES - 1 downto 0);
    signal sdo_index      : std_logic_vector(15 downto 0);
    signal sdo_subindex   : std_logic_vector(7 downto 0);
    signal sdo_timeout    : std_logic_vector(15 downto 0);
    signal sdo_cob_req    : std_logic_vector(10 downto 0);
    signal sdo_cob_resp   : std_logic_vector(10 downto 0);
    signal sdo_chan       : std_logic_vector(1 downto 0);
    signal acfg_fail_sel  : std_logic_vector(3 downto 0);
    signal acfg_nodes     : std_logic;
    signal acfg_entry     : unsigned(7 downto 0);
    signal acfg_node      : std_logic_vector(7 downto 0);
    signal acfg_ref       : std_logic;
    signal acfg_size      : std_logic_vector(2 downto 0);
    signal acfg_index     : std_logic_vector(15 downto 0);
    signal acfg_sub       : std_logic_vector(7 downto 0);

    -- interrupt flags (W1C) and the sticky SDO done flag of each channel
    signal irq_status : std_logic_vector(irq_bits_c - 1 downto 0);
    signal sdo_done   : std_logic_vector(3 downto 0);
    -- SDO_SEL.CHAN as an index
    signal sdo_sel : natural range 0 to 3;
    -- sticky: the configuration list finished, cleared by the next ACFG_CTRL.START
    signal acfg_done : std_logic;

    -- event counter amounts of this cycle, counter i (word REG_CNT_RX_FRAMES_C + i) in bits
    -- 2 * i + 1 .. 2 * i
    signal cnt_inc : std_logic_vector(2 * cnt_num_c - 1 downto 0);
    -- CTRL.CLR_COUNTERS written in this cycle
    signal cnt_clear : std_logic;
    -- counter bank read port: counter number (address - CNT_RX_FRAMES), the address is a
    -- counter, the count of the previous cycle's address
    signal cnt_off   : unsigned(7 downto 0);
    signal cnt_raddr : std_logic_vector(3 downto 0);
    signal cnt_sel   : std_logic;
    signal cnt_rdata : std_logic_vector(CNT_BITS - 1 downto 0);
    -- node status RAM read: offset from NODE_CFG(0), the address is NODE_STATUS / NODE_LAST_MS
    -- of a slot < MAX_NODES, and registered: such a read is selected
    signal nst_off   : unsigned(7 downto 0);
    signal nst_sel   : std_logic;
    signal nlast_sel : std_logic;
    signal rd_nst    : std_logic;
    signal rd_nlast  : std_logic;
    signal nst_word  : std_logic_vector(31 downto 0);
    -- SDO result of the selected channel (canopen_sdo_channels' result RAM, registered like
    -- the node status RAM): the address is SDO_CMD / SDO_ABORT, registered: such a read
    signal scmd_sel  : std_logic;
    signal sabrt_sel : std_logic;
    signal rd_scmd   : std_logic;
    signal rd_sabrt  : std_logic;
    signal sdo_res   : std_logic_vector(31 downto 0);

    -- registered read data: multiplexer output, its register, SDO_BUF selected, valid
    signal rd_mux   : std_logic_vector(31 downto 0);
    signal rd_data  : std_logic_vector(31 downto 0);
    signal rd_buf   : std_logic;
    signal rd_valid : std_logic;
    -- PDO_WIN read: pdo_rdata_i selected
    signal rd_pdo : std_logic;
    -- CNT_* read: the counter bank's read data selected
    signal rd_cnt : std_logic;

    -- RW word RAM. It is read at the bus address itself (avs_address_i goes only into the
    -- RAM's address register, like into av_addr), so the word of the registered request is
    -- there in its act cycle, for the read and for merging a partial write. The *_ok flags mark
    -- the words written since reset (the others read their reset value): fix_ok per fixed
    -- word, cfg_ok / tl_ok per slot; rw_fwd_* hold the word written in the previous cycle,
    -- which the RAM does not return yet for that address
    signal rw_raddr : natural range 0 to rw_depth_c - 1;
    signal rw_addr  : natural range 0 to rw_depth_c - 1;
    signal rw_q     : std_logic_vector(31 downto 0);
    signal rw_fix   : std_logic_vector(rw_fixed_c'range); -- av_addr is fixed word i
    signal fix_ok   : std_logic_vector(rw_fixed_c'range);
    signal cfg_ok   : std_logic_vector(MAX_NODES - 1 downto 0);
    signal tl_ok    : std_logic_vector(MAX_NODES - 1 downto 0);
    -- the addressed word was written since reset
    signal rw_ok_sel   : std_logic;
    signal rw_sel      : std_logic;
    signal rw_wr       : std_logic;
    signal rw_fwd_hit  : std_logic;
    signal rw_old      : std_logic_vector(31 downto 0);
    signal rw_mrg      : std_logic_vector(31 downto 0); -- old word and written bytes
    signal rw_new      : std_logic_vector(31 downto 0); -- its fields: the word stored
    signal rw_fwd_v    : std_logic;
    signal rw_fwd_addr : natural range 0 to rw_depth_c - 1;
    signal rw_fwd_word : std_logic_vector(31 downto 0);
    -- NODE_CFG / NODE_TIME of an existing slot, the slot; the NODE_TIME write passed on to the
    -- node monitor one cycle later (tl_we_q with the stored word rw_fwd_word, the slot of
    -- rw_fwd_addr)
    signal cfg_sel   : std_logic;
    signal tl_sel    : std_logic;
    signal tl_slot   : natural range 0 to MAX_NODES - 1;
    signal tl_we_q   : std_logic;
    signal tl_slot_q : natural range 0 to MAX_NODES - 1;

begin

    -- ---------------------------------------------------------------------------------------------
    -- Avalon input registers: every Avalon input ends in a flip-flop (read latency 2)
    -- ---------------------------------------------------------------------------------------------
    av_ctrl_proc : process (clk_i, rst_n_i) is
    begin

        if rst_n_i = '0' then
            av_rd <= '0';
            av_wr <= '0';
        elsif rising_edge(clk_i) then
            av_rd <= avs_read_i;
            av_wr <= avs_write_i;
        end if;

    end process av_ctrl_proc;

    -- datapath, qualified by av_rd / av_wr (no reset)
    av_data_proc : process (clk_i) is
    begin

        if rising_edge(clk_i) then
            av_addr <= avs_address_i;
            av_wd   <= avs_writedata_i;
            av_be   <= avs_byteenable_i;
        end if;

    end process av_data_proc;

    -- ---------------------------------------------------------------------------------------------
    -- Write data qualification
    -- ---------------------------------------------------------------------------------------------

    be_bits_gen : for b in 0 to 3 generate
        be_bits(8 * b + 7 downto 8 * b) <= (others => av_be(b));
    end generate be_bits_gen;

    wr_ones <= av_wd and be_bits;

    sdo_sel <= to_integer(unsigned(sdo_chan));

    buf_sel <= '1' when is_off(av_addr(7 downto buf_bits_c), buf_win_c) else
               '0';
    pdo_sel <= '1' when is_off(av_addr(7 downto pdo_bits_c), pdo_win_c) else
               '0';

    cnt_clear <= '1' when av_wr = '1' and is_off(av_addr, REG_CTRL_C)
                          and wr_ones(CTRL_CLR_COUNTERS_C) = '1' else
                 '0';

    -- ---------------------------------------------------------------------------------------------
    -- Configuration registers, flags and command strobes
    -- ---------------------------------------------------------------------------------------------
    regs_proc : process (clk_i, rst_n_i) is

        variable ev_v : std_logic_vector(irq_bits_c - 1 downto 0);

    begin

        if rst_n_i = '0' then
            sync_en        <= '0';
            omni_en        <= '0';
            irq_enable     <= (others => '0');
            irq_status     <= (others => '0');
            sync_period    <= (others => '0');
            sync_overflow  <= (others => '0');
            ovf_refused    <= '0';
            sync_window    <= (others => '0');
            node_id        <= (others => (others => '0'));
            node_mode      <= (others => (others => '0'));
            node_autostart <= (others => '0');
            node_rst_loss  <= (others => '0');
            sdo_index      <= (others => '0');
            sdo_subindex   <= (others => '0');
            sdo_timeout    <= SDO_TIMEOUT_MS_RESET_C(sdo_timeout'range);
            sdo_cob_req    <= (others => '0');
            sdo_cob_resp   <= (others => '0');
            sdo_chan       <= (others => '0');
            acfg_fail_sel  <= (others => '0');
            sdo_done       <= (others => '0');
            acfg_nodes     <= '0';
            acfg_entry     <= (others => '0');
            acfg_node      <= (others => '0');
            acfg_ref       <= '0';
            acfg_size      <= (others => '0');
            acfg_index     <= (others => '0');
            acfg_sub       <= (others => '0');
            acfg_done      <= '0';
            acfg_start_o   <= '0';
            reinit_o       <= '0';
            node_clear_o   <= (others => '0');
            emcy_clear_o   <= '0';
            emcy_pop_o     <= '0';
            sdo_req_o      <= '0';
        elsif rising_edge(clk_i) then
            -- strobes
            reinit_o     <= '0';
            node_clear_o <= (others => '0');
            emcy_clear_o <= '0';
            emcy_pop_o   <= '0';
            sdo_req_o    <= '0';
            acfg_start_o <= '0';

            -- interrupt flags: clear by writing 1, an event in the same cycle wins
            ev_v                           := (others => '0');
            ev_v(IRQ_STATUS_NODE_C)        := ev_node_i;
            ev_v(IRQ_STATUS_EMCY_C)        := ev_emcy_i;
            ev_v(IRQ_STATUS_SDO_DONE_C)    := or_reduce(ev_sdo_done_i);
            ev_v(IRQ_STATUS_CAN_ERROR_C)   := ev_can_error_i;
            ev_v(IRQ_STATUS_SYNC_C)        := ev_sync_i;
            ev_v(IRQ_STATUS_FRAME_ERROR_C) := ev_frame_error_i;
            ev_v(IRQ_STATUS_INIT_C)        := ev_init_i;
            ev_v(IRQ_STATUS_CONFIG_C)      := ev_acfg_done_i;
            if av_wr = '1' and is_off(av_addr, REG_IRQ_STATUS_C) then
                irq_status <= (irq_status and not wr_ones(irq_status'range)) or ev_v;
            else
                irq_status <= irq_status or ev_v;
            end if;

            -- SDO done per channel: set by its done event, cleared when the channel accepts the
            -- next SDO_CMD write (a refused write leaves it: REFUSED changes nothing else)
            sdo_done <= (sdo_done and not sdo_start_i) or ev_sdo_done_i;
            if ev_acfg_done_i = '1' then
                acfg_done <= '1';
            end if;

            if av_wr = '1' then
                if is_off(av_addr, REG_CTRL_C) then
                    sync_en  <= mrg_bit(sync_en, av_wd, be_bits, CTRL_SYNC_EN_C);
                    omni_en  <= mrg_bit(omni_en, av_wd, be_bits, CTRL_OMNI_C);
                    reinit_o <= wr_ones(CTRL_REINIT_C);
                end if;
                if is_off(av_addr, REG_IRQ_ENABLE_C) then
                    irq_enable <= mrg(irq_enable, av_wd, be_bits, irq_bits_c - 1, 0);
                end if;
                if is_off(av_addr, REG_SYNC_PERIOD_US_C) then
                    sync_period <= mrg(sync_period, av_wd, be_bits,
                                       SYNC_PERIOD_US_VALUE_HI_C, SYNC_PERIOD_US_VALUE_LO_C);
                end if;
                -- CiA 301 1019h: 0 or 2..240; no change while the SYNC producer runs
                if is_off(av_addr, REG_SYNC_OVERFLOW_C) then
                    if sync_ovf_ok(mrg(sync_overflow, av_wd, be_bits, SYNC_OVERFLOW_VALUE_HI_C,
                                       SYNC_OVERFLOW_VALUE_LO_C), sync_overflow,
                                   sync_en = '1' and unsigned(sync_period) /= 0) then
                        sync_overflow <= mrg(sync_overflow, av_wd, be_bits,
                                             SYNC_OVERFLOW_VALUE_HI_C, SYNC_OVERFLOW_VALUE_LO_C);
                        ovf_refused   <= '0';
                    else
                        ovf_refused <= '1';
                    end if;
                end if;
                if is_off(av_addr, REG_SYNC_WINDOW_US_C) then
                    sync_window <= mrg(sync_window, av_wd, be_bits,
                                       SYNC_WINDOW_US_VALUE_HI_C, SYNC_WINDOW_US_VALUE_LO_C);
                end if;
                if is_off(av_addr, REG_EMCY_STATUS_C) then
                    emcy_clear_o <= wr_ones(EMCY_STATUS_LOST_C);
                end if;
                if is_off(av_addr, REG_EMCY_POP_C) then
                    emcy_pop_o <= '1';
                end if;
                if is_off(av_addr, REG_SDO_OBJ_C) then
                    sdo_index    <= mrg(sdo_index, av_wd, be_bits,
                                        SDO_OBJ_INDEX_HI_C, SDO_OBJ_INDEX_LO_C);
                    sdo_subindex <= mrg(sdo_subindex, av_wd, be_bits,
                                        SDO_OBJ_SUBINDEX_HI_C, SDO_OBJ_SUBINDEX_LO_C);
                end if;
                if is_off(av_addr, REG_SDO_CMD_C) then
                    sdo_req_o <= '1';
                end if;
                -- a channel number the core does not have is ignored
                if is_off(av_addr, REG_SDO_SEL_C)
                   and to_integer(unsigned(mrg(sdo_chan, av_wd, be_bits, SDO_SEL_CHAN_HI_C,
                                                  SDO_SEL_CHAN_LO_C))) < N_SDO then
                    sdo_chan <= mrg(sdo_chan, av_wd, be_bits, SDO_SEL_CHAN_HI_C, SDO_SEL_CHAN_LO_C);
                end if;
                if is_off(av_addr, REG_ACFG_FAIL_SEL_C) then
                    acfg_fail_sel <= mrg(acfg_fail_sel, av_wd, be_bits,
                                         ACFG_FAIL_SEL_INDEX_HI_C, ACFG_FAIL_SEL_INDEX_LO_C);
                end if;
                if is_off(av_addr, REG_SDO_TIMEOUT_MS_C) then
                    sdo_timeout <= mrg(sdo_timeout, av_wd, be_bits,
                                       SDO_TIMEOUT_MS_VALUE_HI_C, SDO_TIMEOUT_MS_VALUE_LO_C);
                end if;
                if is_off(av_addr, REG_SDO_COB_C) then
                    sdo_cob_req  <= mrg(sdo_cob_req, av_wd, be_bits,
                                        SDO_COB_REQUEST_HI_C, SDO_COB_REQUEST_LO_C);
                    sdo_cob_resp <= mrg(sdo_cob_resp, av_wd, be_bits,
                                        SDO_COB_RESPONSE_HI_C, SDO_COB_RESPONSE_LO_C);
                end if;
                if is_off(av_addr, REG_ACFG_CTRL_C) then
                    acfg_nodes   <= mrg_bit(acfg_nodes, av_wd, be_bits, ACFG_CTRL_START_NODES_C);
                    acfg_start_o <= wr_ones(ACFG_CTRL_START_C);
                    if wr_ones(ACFG_CTRL_START_C) = '1' then
                        acfg_done <= '0';
                    end if;
                end if;
                if is_off(av_addr, REG_ACFG_ENTRY_C) then
                    acfg_entry <= unsigned(mrg(std_logic_vector(acfg_entry), av_wd, be_bits,
                                               ACFG_ENTRY_ENTRY_HI_C, ACFG_ENTRY_ENTRY_LO_C));
                    acfg_node  <= mrg(acfg_node, av_wd, be_bits,
                                      ACFG_ENTRY_NODE_HI_C, ACFG_ENTRY_NODE_LO_C);
                    acfg_size  <= mrg(acfg_size, av_wd, be_bits,
                                      ACFG_ENTRY_SIZE_HI_C, ACFG_ENTRY_SIZE_LO_C);
                end if;
                if is_off(av_addr, REG_ACFG_OBJ_C) then
                    acfg_index <= mrg(acfg_index, av_wd, be_bits,
                                      ACFG_OBJ_INDEX_HI_C, ACFG_OBJ_INDEX_LO_C);
                    acfg_sub   <= mrg(acfg_sub, av_wd, be_bits,
                                      ACFG_OBJ_SUBINDEX_HI_C, ACFG_OBJ_SUBINDEX_LO_C);
                end if;
                -- ACFG_VALUE: store the entry now, then point at the next one
                -- (an entry with NODE > 127, or a size other than 1..4, is refused)
                if is_off(av_addr, REG_ACFG_VALUE_C) then
                    if acfg_entry_ok(acfg_node, acfg_size) then
                        acfg_entry <= acfg_entry + 1;
                        acfg_ref   <= '0';
                    else
                        acfg_ref <= '1';
                    end if;
                end if;

                -- node slots (static indices)
                for k in 0 to MAX_NODES - 1 loop

                    if is_off(av_addr, REG_NODE_CFG_C + k * REG_NODE_STRIDE_C) then
                        node_id(k)        <= mrg(node_id(k), av_wd, be_bits,
                                                 NODE_CFG_NODE_ID_HI_C, NODE_CFG_NODE_ID_LO_C);
                        node_mode(k)      <= mrg(node_mode(k), av_wd, be_bits,
                                                 NODE_CFG_MODE_HI_C, NODE_CFG_MODE_LO_C);
                        node_autostart(k) <= mrg_bit(node_autostart(k), av_wd, be_bits,
                                                     NODE_CFG_AUTOSTART_C);
                        node_rst_loss(k)  <= mrg_bit(node_rst_loss(k), av_wd, be_bits,
                                                     NODE_CFG_RESET_ON_LOSS_C);
                    end if;
                    if is_off(av_addr, REG_NODE_STATUS_C + k * REG_NODE_STRIDE_C) then
                        node_clear_o(k) <= wr_ones(NODE_STATUS_LOST_C)
                                           or wr_ones(NODE_STATUS_TOGGLE_ERR_C)
                                           or wr_ones(NODE_STATUS_BOOTUP_C);
                    end if;

                end loop;

            end if;
        end if;

    end process regs_proc;

    -- ---------------------------------------------------------------------------------------------
    -- Commands acted on in the act cycle: NMT_CMD and ACFG_VALUE drive their strobe and fields
    -- straight from the registered request (av_*), because their consumers keep the fields
    -- themselves (canopen_tx_path's waiting NMT command, canopen_autoconfig's table RAM): a
    -- second register here would only hold a copy
    -- ---------------------------------------------------------------------------------------------
    nmt_req_o  <= '1' when av_wr = '1' and is_off(av_addr, REG_NMT_CMD_C) else
                  '0';
    nmt_cs_o   <= av_wd(NMT_CMD_CS_HI_C downto NMT_CMD_CS_LO_C);
    nmt_node_o <= av_wd(NMT_CMD_NODE_HI_C downto NMT_CMD_NODE_LO_C);

    -- the entry is stored at the end of the act cycle, where acfg_entry still points at it
    acfg_tbl_we_o    <= '1' when av_wr = '1' and is_off(av_addr, REG_ACFG_VALUE_C)
                                 and acfg_entry_ok(acfg_node, acfg_size) else
                        '0';
    acfg_tbl_addr_o  <= std_logic_vector(acfg_entry);
    acfg_tbl_value_o <= av_wd;

    -- ---------------------------------------------------------------------------------------------
    -- SDO_CMD fields: datapath, qualified by sdo_req_o (no reset); registered like the other
    -- strobes, because the SDO channels decide on the request in the cycle of the strobe
    -- ---------------------------------------------------------------------------------------------
    cmd_data_proc : process (clk_i) is
    begin

        if rising_edge(clk_i) then
            if av_wr = '1' and is_off(av_addr, REG_SDO_CMD_C) then
                sdo_node_o   <= av_wd(SDO_CMD_NODE_HI_C downto SDO_CMD_NODE_LO_C);
                sdo_upload_o <= av_wd(SDO_CMD_UPLOAD_C);
                sdo_size_o   <= av_wd(SDO_CMD_SIZE_HI_C downto SDO_CMD_SIZE_LO_C);
            end if;
        end if;

    end process cmd_data_proc;

    -- ---------------------------------------------------------------------------------------------
    -- Event counters: saturating, cleared by CTRL.CLR_COUNTERS, in a RAM with one incrementer
    -- ---------------------------------------------------------------------------------------------
    -- amount of counter i: 1 per strobe; cnt_rx_overflow_i its number of set bits (0..2)
    cnt_inc <= '0' & cnt_emcy_i & '0' & cnt_can_error_i & '0' & cnt_guard_err_i
               & '0' & cnt_hb_loss_i & '0' & cnt_sdo_abort_i & '0' & cnt_tx_error_i
               & (cnt_rx_overflow_i(1) and cnt_rx_overflow_i(0))
               & (cnt_rx_overflow_i(1) xor cnt_rx_overflow_i(0))
               & '0' & cnt_malformed_i & '0' & cnt_unexpected_i & '0' & cnt_tx_frame_i
               & '0' & cnt_rx_frame_i;

    -- ---------------------------------------------------------------------------------------------
    -- RW word RAM: read at the bus address (the word of av_addr in the act cycle); the old word
    -- (the previous cycle's write to the same address, the RAM's word if written since reset,
    -- else the reset value) is read and merged with the enabled bytes of a write, which stores
    -- the word (its fields only) at the end of the act cycle. NODE_TIME is passed on to the
    -- node monitor from here
    -- ---------------------------------------------------------------------------------------------
    rw_raddr <= to_integer(unsigned(avs_address_i(6 downto 0)));
    rw_addr  <= to_integer(unsigned(av_addr(6 downto 0)));

    rw_fix_gen : for i in rw_fixed_c'range generate
        rw_fix(i) <= '1' when is_off(av_addr, rw_fixed_c(i)) else
                     '0';
    end generate rw_fix_gen;

    tl_slot <= slot_of(av_addr);
    cfg_sel <= '1' when nst_off < MAX_NODES * REG_NODE_STRIDE_C and nst_off(1 downto 0) = 0 else
               '0';
    tl_sel  <= '1' when nst_off < MAX_NODES * REG_NODE_STRIDE_C
                        and nst_off(1 downto 0) = REG_NODE_TIME_C - REG_NODE_CFG_C else
               '0';
    rw_sel  <= or_reduce(rw_fix) or cfg_sel or tl_sel;
    rw_wr   <= av_wr and rw_sel;

    -- the addressed word's flag (qualified by rw_sel: a fixed word's, else the slot's)
    rw_ok_sel <= or_reduce(rw_fix and fix_ok) when or_reduce(rw_fix) = '1' else
                 cfg_ok(tl_slot) when av_addr(0) = '0' else
                 tl_ok(tl_slot);

    rw_fwd_hit <= '1' when rw_fwd_v = '1' and rw_fwd_addr = rw_addr else
                  '0';
    rw_old     <= rw_fwd_word when rw_fwd_hit = '1' else
                  rw_q when rw_ok_sel = '1' else
                  rw_reset(av_addr);
    rw_mrg     <= (rw_old and not be_bits) or wr_ones;
    rw_new     <= rw_mrg and rw_mask(av_addr);

    rw_ram_inst : entity work.canopen_sdp_ram
        generic map (
            DEPTH => rw_depth_c,
            WIDTH => 32
        )
        port map (
            clk_i   => clk_i,
            we_i    => rw_wr,
            waddr_i => rw_addr,
            wdata_i => rw_new,
            re_i    => '1',
            raddr_i => rw_raddr,
            rdata_o => rw_q
        );

    -- a NODE_TIME word counts as written from the edge where the node monitor stores it
    rw_ctrl_proc : process (clk_i, rst_n_i) is
    begin

        if rst_n_i = '0' then
            fix_ok   <= (others => '0');
            cfg_ok   <= (others => '0');
            tl_ok    <= (others => '0');
            rw_fwd_v <= '0';
            tl_we_q  <= '0';
        elsif rising_edge(clk_i) then
            rw_fwd_v <= rw_wr;
            tl_we_q  <= av_wr and tl_sel;
            if av_wr = '1' then
                fix_ok <= fix_ok or rw_fix;
            end if;
            if av_wr = '1' and cfg_sel = '1' then
                cfg_ok(tl_slot) <= '1';
            end if;
            if tl_we_q = '1' then
                tl_ok(tl_slot_q) <= '1';
            end if;
        end if;

    end process rw_ctrl_proc;

    -- datapath, qualified by rw_fwd_v and tl_we_q (no reset)
    rw_fwd_proc : process (clk_i) is
    begin

        if rising_edge(clk_i) then
            rw_fwd_addr <= rw_addr;
            rw_fwd_word <= rw_new;
        end if;

    end process rw_fwd_proc;

    tl_slot_q <= slot_of(std_logic_vector(to_unsigned(rw_fwd_addr, 8)));

    node_tl_we_o   <= tl_we_q;
    node_tl_slot_o <= std_logic_vector(to_unsigned(tl_slot_q, 5));
    node_tl_time_o <= rw_fwd_word(NODE_TIME_TIME_MS_HI_C downto NODE_TIME_TIME_MS_LO_C);
    node_tl_life_o <= rw_fwd_word(NODE_TIME_LIFE_FACTOR_HI_C downto NODE_TIME_LIFE_FACTOR_LO_C);
    node_tl_ok_o   <= tl_ok;

    -- ---------------------------------------------------------------------------------------------
    -- Node status RAM read port (canopen_node_monitor): the slot of the addressed NODE_STATUS /
    -- NODE_LAST_MS in the act cycle, the RAM's registered data selected in the next
    -- ---------------------------------------------------------------------------------------------
    nst_off        <= unsigned(av_addr) - REG_NODE_CFG_C;
    node_st_slot_o <= '0' & std_logic_vector(nst_off(5 downto 2));
    node_st_nmt_o  <= nst_sel;
    nst_sel        <= '1' when nst_off < MAX_NODES * REG_NODE_STRIDE_C
                               and nst_off(1 downto 0) = REG_NODE_STATUS_C - REG_NODE_CFG_C else
                      '0';
    nlast_sel      <= '1' when nst_off < MAX_NODES * REG_NODE_STRIDE_C
                               and nst_off(1 downto 0) = REG_NODE_LAST_MS_C - REG_NODE_CFG_C else
                      '0';

    -- SDO result (canopen_sdo_channels, +1 cycle after SDO_SEL like a RAM read): SDO_CMD
    -- XFER_SIZE / ABORT_SENT and SDO_ABORT are selected in the output stage
    scmd_sel  <= '1' when is_off(av_addr, REG_SDO_CMD_C) else
                 '0';
    sabrt_sel <= '1' when is_off(av_addr, REG_SDO_ABORT_C) else
                 '0';

    cnt_off   <= unsigned(av_addr) - REG_CNT_RX_FRAMES_C;
    cnt_raddr <= std_logic_vector(cnt_off(3 downto 0));
    cnt_sel   <= '1' when cnt_off < cnt_num_c else
                 '0';

    cnt_bank_inst : entity work.canopen_counter_bank
        generic map (
            N_CNT    => cnt_num_c,
            CNT_BITS => CNT_BITS,
            INC_BITS => 2
        )
        port map (
            clk_i     => clk_i,
            rst_n_i   => rst_n_i,
            inc_i     => cnt_inc,
            clr_i     => cnt_clear,
            rd_addr_i => cnt_raddr,
            rd_data_o => cnt_rdata
        );

    -- ---------------------------------------------------------------------------------------------
    -- Read multiplexer: OR of the words whose (disjoint) address matches; registered below
    -- ---------------------------------------------------------------------------------------------
    read_mux_proc : process (acfg_busy_i, acfg_done, acfg_entry, acfg_fail_abort_i,
                             acfg_fail_entry_i, acfg_fail_node_i, acfg_node, acfg_nodes,
                             acfg_nodes_fail_i, acfg_nodes_ok_i, acfg_ref, acfg_refused_i,
                             acfg_size, av_addr, bus_off_i, ctrl_busy_i, eflg_i, emcy_count_i,
                             emcy_data_i, emcy_lost_i, emcy_node_i, emcy_time_i, err_passive_i,
                             fsm_state_i, init_done_i, init_fail_i, irq_status, nmt_busy_i,
                             nmt_refused_i, node_alive_i, node_bootup_i, node_lost_i,
                             node_toggle_i, omni_en, ovf_refused, rec_i, rw_old, rw_sel,
                             sdo_busy_i, sdo_chan, sdo_chan_busy_i, sdo_done, sdo_error_i,
                             sdo_refused_i, sdo_sel, sdo_start_i, sync_count_i, sync_en,
                             sync_overflow, tec_i, time_us_i, tx_pending_i) is

        -- the address and the word being built (put: canopen_util_pkg)
        variable a : std_logic_vector(7 downto 0);
        variable v : std_logic_vector(31 downto 0);

    begin

        a := av_addr;
        v := (others => '0');

        put(v, a, REG_ID_C, ID_RESET_C);
        put(v, a, REG_VERSION_C, VERSION_RESET_C);
        put(v, a, REG_CTRL_C, at(sync_en, CTRL_SYNC_EN_C) or at(omni_en, CTRL_OMNI_C));
        put(v, a, REG_STATUS_C,
            at(fsm_state_i, STATUS_FSM_STATE_HI_C, STATUS_FSM_STATE_LO_C)
            or at(init_done_i, STATUS_INIT_DONE_C) or at(init_fail_i, STATUS_INIT_FAIL_C)
            or at(ctrl_busy_i, STATUS_CTRL_BUSY_C)
            or at(tx_pending_i, STATUS_TX_PENDING_HI_C, STATUS_TX_PENDING_LO_C)
            or at(bus_off_i, STATUS_BUS_OFF_C) or at(err_passive_i, STATUS_ERR_PASSIVE_C));
        put(v, a, REG_IRQ_STATUS_C, at(irq_status, irq_bits_c - 1, 0));
        put(v, a, REG_NMT_CMD_C,
            at(nmt_busy_i, NMT_CMD_NMT_BUSY_C) or at(nmt_refused_i, NMT_CMD_REFUSED_C));
        put(v, a, REG_SYNC_OVERFLOW_C,
            at(sync_overflow, SYNC_OVERFLOW_VALUE_HI_C, SYNC_OVERFLOW_VALUE_LO_C)
            or at(ovf_refused, SYNC_OVERFLOW_REFUSED_C));
        put(v, a, REG_SYNC_COUNT_C, sync_count_i);
        put(v, a, REG_TIME_US_C, time_us_i);
        put(v, a, REG_CAN_STATUS_C,
            at(tec_i, CAN_STATUS_TEC_HI_C, CAN_STATUS_TEC_LO_C)
            or at(rec_i, CAN_STATUS_REC_HI_C, CAN_STATUS_REC_LO_C)
            or at(eflg_i, CAN_STATUS_EFLG_HI_C, CAN_STATUS_EFLG_LO_C));

        -- CNT_*: the counter bank's registered read data, selected after the read (rd_cnt)

        for k in 0 to MAX_NODES - 1 loop

            -- NODE_CFG, NODE_TIME: the RW word RAM, below; NMT_STATE and NODE_LAST_MS: the
            -- status RAM's data, selected after the read
            put(v, a, REG_NODE_STATUS_C + k * REG_NODE_STRIDE_C,
                at(node_alive_i(k), NODE_STATUS_ALIVE_C)
                or at(node_lost_i(k), NODE_STATUS_LOST_C)
                or at(node_toggle_i(k), NODE_STATUS_TOGGLE_ERR_C)
                or at(node_bootup_i(k), NODE_STATUS_BOOTUP_C));

        end loop;

        put(v, a, REG_EMCY_STATUS_C,
            at(emcy_count_i, EMCY_STATUS_COUNT_HI_C, EMCY_STATUS_COUNT_LO_C)
            or at(emcy_lost_i, EMCY_STATUS_LOST_C));
        put(v, a, REG_EMCY_NODE_C, at(emcy_node_i, EMCY_NODE_NODE_HI_C, EMCY_NODE_NODE_LO_C));
        put(v, a, REG_EMCY_DATA_LO_C, emcy_data_i(31 downto 0));
        put(v, a, REG_EMCY_DATA_HI_C, emcy_data_i(63 downto 32));
        put(v, a, REG_EMCY_TIME_MS_C, emcy_time_i);
        put(v, a, REG_SDO_CMD_C,
            at(sdo_busy_i, SDO_CMD_BUSY_C)
            or at(sdo_done(sdo_sel) and not sdo_start_i(sdo_sel), SDO_CMD_DONE_C)
            or at(sdo_error_i, SDO_CMD_ERROR_C) or at(sdo_refused_i, SDO_CMD_REFUSED_C));
        put(v, a, REG_SDO_SEL_C,
            at(sdo_chan, SDO_SEL_CHAN_HI_C, SDO_SEL_CHAN_LO_C)
            or at(sdo_done and not sdo_start_i, SDO_SEL_DONE_HI_C, SDO_SEL_DONE_LO_C)
            or at(sdo_chan_busy_i, SDO_SEL_BUSY_HI_C, SDO_SEL_BUSY_LO_C)
            or at(std_logic_vector(to_unsigned(N_SDO, 3)), SDO_SEL_CHANNELS_HI_C,
                     SDO_SEL_CHANNELS_LO_C));

        put(v, a, REG_ACFG_CTRL_C, at(acfg_nodes, ACFG_CTRL_START_NODES_C));
        put(v, a, REG_ACFG_STATUS_C,
            at(acfg_busy_i, ACFG_STATUS_BUSY_C) or at(acfg_done, ACFG_STATUS_DONE_C)
            or at(acfg_refused_i, ACFG_STATUS_REFUSED_C)
            or at(acfg_nodes_ok_i, ACFG_STATUS_NODES_OK_HI_C, ACFG_STATUS_NODES_OK_LO_C)
            or at(acfg_nodes_fail_i, ACFG_STATUS_NODES_FAIL_HI_C, ACFG_STATUS_NODES_FAIL_LO_C));
        put(v, a, REG_ACFG_FAIL_C,
            at(acfg_fail_node_i, ACFG_FAIL_NODE_HI_C, ACFG_FAIL_NODE_LO_C)
            or at(acfg_fail_entry_i, ACFG_FAIL_ENTRY_HI_C, ACFG_FAIL_ENTRY_LO_C));
        put(v, a, REG_ACFG_ABORT_C, acfg_fail_abort_i);
        put(v, a, REG_ACFG_ENTRY_C,
            at(std_logic_vector(acfg_entry), ACFG_ENTRY_ENTRY_HI_C, ACFG_ENTRY_ENTRY_LO_C)
            or at(acfg_node, ACFG_ENTRY_NODE_HI_C, ACFG_ENTRY_NODE_LO_C)
            or at(acfg_size, ACFG_ENTRY_SIZE_HI_C, ACFG_ENTRY_SIZE_LO_C)
            or at(acfg_ref, ACFG_ENTRY_REFUSED_C));

        -- the RW word RAM's words
        if rw_sel = '1' then
            v := v or rw_old;
        end if;

        rd_mux <= v;

    end process read_mux_proc;

    -- read data register: datapath, qualified by rd_valid (no reset)
    rd_data_proc : process (clk_i) is
    begin

        if rising_edge(clk_i) then
            if av_rd = '1' then
                rd_data <= rd_mux;
            end if;
        end if;

    end process rd_data_proc;

    rd_ctrl_proc : process (clk_i, rst_n_i) is
    begin

        if rst_n_i = '0' then
            rd_valid <= '0';
            rd_buf   <= '0';
            rd_pdo   <= '0';
            rd_cnt   <= '0';
            rd_nst   <= '0';
            rd_nlast <= '0';
            rd_scmd  <= '0';
            rd_sabrt <= '0';
        elsif rising_edge(clk_i) then
            rd_valid <= av_rd;
            if av_rd = '1' then
                rd_buf   <= buf_sel;
                rd_pdo   <= pdo_sel;
                rd_cnt   <= cnt_sel;
                rd_nst   <= nst_sel;
                rd_nlast <= nlast_sel;
                rd_scmd  <= scmd_sel;
                rd_sabrt <= sabrt_sel;
            end if;
        end if;

    end process rd_ctrl_proc;

    avs_readdata_o <= sdo_buf_rdata_i when rd_buf = '1' else
                      pdo_rdata_i when rd_pdo = '1' else
                      std_logic_vector(resize(unsigned(cnt_rdata), 32)) when rd_cnt = '1' else
                      rd_data or nst_word or sdo_res;
    -- the status RAM's word: NODE_LAST_MS, or NODE_STATUS.NMT_STATE in bits 6..0 (zeros above)
    nst_word            <= node_st_data_i when rd_nst = '1' or rd_nlast = '1' else
                           (others => '0');
    sdo_res             <= at(sdo_size_i, SDO_CMD_XFER_SIZE_HI_C, SDO_CMD_XFER_SIZE_LO_C)
                           or at(sdo_abort_sent_i, SDO_CMD_ABORT_SENT_C) when rd_scmd = '1' else
                           sdo_abort_code_i when rd_sabrt = '1' else
                           (others => '0');
    avs_readdatavalid_o <= rd_valid;

    irq_o <= '1' when (irq_status and irq_enable) /= (irq_status'range => '0') else
             '0';

    -- ---------------------------------------------------------------------------------------------
    -- SDO_BUF pass-through (the RAM registers its read data: one cycle, like every register)
    -- ---------------------------------------------------------------------------------------------
    sdo_buf_addr_o  <= std_logic_vector(resize(unsigned(av_addr(buf_bits_c - 1 downto 0)),
                                               sdo_buf_addr_o'length));
    sdo_buf_we_o    <= av_wr and buf_sel when av_be = "1111" else
                       '0';
    sdo_buf_wdata_o <= av_wd;

    -- ---------------------------------------------------------------------------------------------
    -- PDO_WIN pass-through (the engine registers its read data: one cycle, like every register)
    -- ---------------------------------------------------------------------------------------------
    pdo_addr_o  <= av_addr(pdo_bits_c - 1 downto 0);
    pdo_we_o    <= av_wr and pdo_sel when av_be = "1111" else
                   '0';
    pdo_wdata_o <= av_wd;

    -- ---------------------------------------------------------------------------------------------
    -- Configuration outputs
    -- ---------------------------------------------------------------------------------------------

    slot_out_gen : for k in 0 to MAX_NODES - 1 generate
        node_cfg_node_o(7 * k + 6 downto 7 * k) <= node_id(k);
        node_cfg_mode_o(2 * k + 1 downto 2 * k) <= node_mode(k);
    end generate slot_out_gen;

    sync_en_o                <= sync_en;
    omni_en_o                <= omni_en;
    sync_period_us_o         <= sync_period;
    sync_overflow_o          <= sync_overflow;
    sync_window_us_o         <= sync_window;
    node_cfg_autostart_o     <= node_autostart;
    node_cfg_reset_on_loss_o <= node_rst_loss;
    sdo_index_o              <= sdo_index;
    sdo_subindex_o           <= sdo_subindex;
    sdo_timeout_ms_o         <= sdo_timeout;
    sdo_cob_req_o            <= sdo_cob_req;
    sdo_cob_resp_o           <= sdo_cob_resp;
    sdo_chan_o               <= sdo_chan;
    -- the failure log's read address follows a write at once, so a read in the next cycle
    -- already shows the selected failure (the log RAM registers its read data)
    acfg_fail_sel_o    <= mrg(acfg_fail_sel, av_wd, be_bits,
                                 ACFG_FAIL_SEL_INDEX_HI_C, ACFG_FAIL_SEL_INDEX_LO_C)
                          when av_wr = '1'
                               and is_off(av_addr, REG_ACFG_FAIL_SEL_C) else
                          acfg_fail_sel;
    acfg_start_nodes_o <= acfg_nodes;
    acfg_tbl_node_o    <= acfg_node(6 downto 0);
    acfg_tbl_index_o   <= acfg_index;
    acfg_tbl_sub_o     <= acfg_sub;
    acfg_tbl_size_o    <= acfg_size;

end architecture rtl;
