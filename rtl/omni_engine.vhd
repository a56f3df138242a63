-- =================================================================================================
-- Title    : omni_engine
-- Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
-- SPDX-License-Identifier: Apache-2.0
-- =================================================================================================
-- Module:
--   The Omni-ID protocol engine of the master (NCTU 2007 thesis, digest
--   shared/spec/nctu_omni_sync.md section 2): 11-bit id = function code (3) << 8 | node (8).
--   Sibling of canopen_pdo_engine: in Omni-ID mode (CTRL.OMNI) the core hands it every received
--   frame (St5), sends its frames (St8), preloads its cycle frame into TXB2 for the exact-period
--   cycle instant and maps the host window C0h..FFh to its register port.
-- Purpose:
--   * Cycle frame: the broadcast of N_AXES set-points (fc 001, 1 byte per axis, optional
--     sender byte; or fc 100, 2 bytes per axis), highest axis first. Set-points are double
--     buffered: COMMIT copies the staging registers into the committed set; a builder makes
--     its broadcast frame one byte per cycle (one shared multiplexer instead of one per frame
--     bit) and swaps it in whole 10 cycles after the COMMIT or OMNI_CFG write, so a frame
--     never mixes two commits or two configurations. The commit is applied (PENDING falls)
--     at the first cyc_take_i (the preload of the cycle frame) at least 10 cycles after it;
--     a take before sends the previous frame. SYNC_MODE 1: the cycle frame of every K-th
--     cycle is the Omni SYNC (080h, DLC 0)
--     and that cycle's broadcast follows through tx_req_o right after the cycle instant.
--   * Frame queue (tx_req_o / tx_ack_i, one frame at a time, fixed priority): NMT stop all
--     after a missing node, host NMT, broadcast after a SYNC, node query, query reply,
--     parameter frame.
--   * Node table (N_SLOTS, entity omni_node_table): feedback frames (fc 010/011/101/110 to
--     MASTER_ID, byte 0 = the slot's node) stored in a RAM with sequence number and cycle
--     counter; length errors, missed cycles; node query every M cycles with a reply window
--     (here), ALIVE / MISSING bitmaps.
--   * Parameter frames (fc 111) out, parameter mailbox in.
--   * Feasibility: worst-case bits of one cycle against the period (feasible_o, entity
--     omni_feasibility).
--   Registers: OMNI_* in canopen_regs_pkg (scripts/regmap.py). Timing and decisions:
--   docs/omni_engine.md.
-- =================================================================================================

library ieee;
    use ieee.std_logic_1164.all;
    use ieee.numeric_std.all;

library work;
    use work.canopen_regs_pkg.all;
    use work.canopen_util_pkg.all;

entity omni_engine is
    generic (
        MASTER_ID_DEFAULT : natural range 1 to 255 := 2;        -- OMNI_CFG.MASTER_ID at reset
        N_SLOTS           : positive range 1 to 8  := 8;        -- node-table slots
        BITRATE_BPS       : positive               := 1_000_000 -- CAN bit rate (feasibility)
    );
    port (
        -- clock and reset
        clk_i   : in    std_logic; -- system clock
        rst_n_i : in    std_logic; -- async reset, active low (synced)
        -- mode and timing from the core
        enable_i    : in    std_logic;                     -- Omni-ID mode on (CTRL.OMNI)
        tick_us_i   : in    std_logic;                     -- 1-cycle strobe every us
        period_us_i : in    std_logic_vector(31 downto 0); -- cycle period (SYNC_PERIOD_US)
        -- cycle frame (TXB2, fired at the cycle instant)
        cycle_i    : in    std_logic;                     -- strobe: the cycle frame was fired
        cyc_id_o   : out   std_logic_vector(10 downto 0); -- frame for the next cycle instant
        cyc_dlc_o  : out   std_logic_vector(3 downto 0);  -- its DLC
        cyc_data_o : out   std_logic_vector(63 downto 0); -- its data, byte k at 8k+7..8k
        cyc_take_i : in    std_logic;                     -- strobe: the core copied cyc_*
        feasible_o : out   std_logic;                     -- '0': the cycle cannot fit
        -- host register window (C0h..FFh with CTRL.OMNI = 1)
        reg_addr_i  : in    std_logic_vector(5 downto 0);  -- word offset in the window
        reg_we_i    : in    std_logic;                     -- write reg_wdata_i
        reg_wdata_i : in    std_logic_vector(31 downto 0); -- write data
        reg_rdata_o : out   std_logic_vector(31 downto 0); -- word at reg_addr_i, 1 cycle later
        -- received frame (from the FSM, St5): rx_id_i .. rx_data_i are read where they are,
        -- not copied: the caller holds them from rx_valid_i until rx_done_o
        rx_valid_i      : in    std_logic;                     -- strobe: process this frame
        rx_id_i         : in    std_logic_vector(10 downto 0); -- identifier
        rx_rtr_i        : in    std_logic;                     -- remote frame
        rx_dlc_i        : in    std_logic_vector(3 downto 0);  -- data length code
        rx_data_i       : in    std_logic_vector(63 downto 0); -- byte k at 8k+7..8k
        rx_done_o       : out   std_logic;                     -- strobe: frame processed
        rx_reply_o      : out   std_logic;                     -- with rx_done_o: reply queued
        rx_unexpected_o : out   std_logic;                     -- with rx_done_o: nobody's
        -- frame to transmit (towards the FSM, St8)
        tx_req_o  : out   std_logic;                     -- level: a frame is waiting
        tx_id_o   : out   std_logic_vector(10 downto 0); -- identifier
        tx_rtr_o  : out   std_logic;                     -- remote frame
        tx_dlc_o  : out   std_logic_vector(3 downto 0);  -- data length code
        tx_data_o : out   std_logic_vector(63 downto 0); -- byte k at 8k+7..8k
        tx_ack_i  : in    std_logic;                     -- strobe: frame taken
        -- host interrupt event
        ev_o : out   std_logic -- strobe: feedback stored, node missing, parameter received
    );
end entity omni_engine;

architecture rtl of omni_engine is

    -- ---------------------------------------------------------------------------------------------
    -- Protocol constants (digest 2.1-2.4; A3, A6, A12)
    -- ---------------------------------------------------------------------------------------------
    constant fc_nmt_c    : std_logic_vector(2 downto 0)  := "000";         -- NMT, query, replies
    constant fc_bc8_c    : std_logic_vector(2 downto 0)  := "001";         -- broadcast 8 x 1 byte
    constant fc_bc4_c    : std_logic_vector(2 downto 0)  := "100";         -- broadcast 4 x 2 bytes
    constant fc_param_c  : std_logic_vector(2 downto 0)  := "111";         -- parameter setup
    constant sync_id_c   : std_logic_vector(10 downto 0) := "000" & x"80"; -- Omni SYNC (A6)
    constant nmt_dlc_c   : std_logic_vector(3 downto 0)  := x"2";          -- [node][state]
    constant param_min_c : natural                       := 2;             -- [sender][type]
    constant max_axes_c  : natural                       := 8;             -- staging registers

    -- register window offsets (address - REG_OMNI_WIN_C)
    constant off_info_c  : natural := REG_OMNI_INFO_C - REG_OMNI_WIN_C;
    constant off_cfg_c   : natural := REG_OMNI_CFG_C - REG_OMNI_WIN_C;
    constant off_ctrl_c  : natural := REG_OMNI_CTRL_C - REG_OMNI_WIN_C;
    constant off_stat_c  : natural := REG_OMNI_STATUS_C - REG_OMNI_WIN_C;
    constant off_k_c     : natural := REG_OMNI_SYNC_K_C - REG_OMNI_WIN_C;
    constant off_poll_c  : natural := REG_OMNI_POLL_C - REG_OMNI_WIN_C;
    constant off_qwin_c  : natural := REG_OMNI_QUERY_WIN_C - REG_OMNI_WIN_C;
    constant off_cycle_c : natural := REG_OMNI_CYCLE_C - REG_OMNI_WIN_C;
    constant off_sp_c    : natural := REG_OMNI_SP01_C - REG_OMNI_WIN_C;
    constant off_nmt_c   : natural := REG_OMNI_NMT_C - REG_OMNI_WIN_C;
    constant off_phdr_c  : natural := REG_OMNI_PARAM_HDR_C - REG_OMNI_WIN_C;
    constant off_plo_c   : natural := REG_OMNI_PARAM_LO_C - REG_OMNI_WIN_C;
    constant off_phi_c   : natural := REG_OMNI_PARAM_HI_C - REG_OMNI_WIN_C;
    constant off_sel_c   : natural := REG_OMNI_SEL_C - REG_OMNI_WIN_C;
    constant off_scfg_c  : natural := REG_OMNI_SLOT_CFG_C - REG_OMNI_WIN_C;
    constant off_fbnew_c : natural := REG_OMNI_FB_NEW_C - REG_OMNI_WIN_C;
    constant off_miss_c  : natural := REG_OMNI_MISSING_C - REG_OMNI_WIN_C;
    constant off_pmbi_c  : natural := REG_OMNI_PMB_INFO_C - REG_OMNI_WIN_C;
    constant off_pmblo_c : natural := REG_OMNI_PMB_LO_C - REG_OMNI_WIN_C;
    constant off_pmbhi_c : natural := REG_OMNI_PMB_HI_C - REG_OMNI_WIN_C;
    constant off_bits_c  : natural := REG_OMNI_BUS_BITS_C - REG_OMNI_WIN_C;
    constant off_cnt_c   : natural := REG_OMNI_CNT_FB_RX_C - REG_OMNI_WIN_C;
    -- counters, in address order from OMNI_CNT_FB_RX
    constant cnt_fb_c     : natural := 0;
    constant cnt_len_c    : natural := 1;
    constant cnt_unexp_c  : natural := 2;
    constant cnt_miss_c   : natural := 3;
    constant cnt_nmiss_c  : natural := 4;
    constant cnt_refuse_c : natural := 5;
    constant cnt_tx_c     : natural := 6;
    constant cnt_late_c   : natural := 7;
    constant cnt_prx_c    : natural := 8;
    constant cnt_num_c    : natural := 9;
    -- bits of a counter's amount per cycle (OMNI_CNT_MISSED / NODE_MISSING: up to N_SLOTS = 8)
    constant inc_w_c : natural := 4;

    function check_config return boolean is
    begin

        assert REG_OMNI_WIN_WORDS_C = 64
            report "omni_engine: the register window must be 64 words (6-bit offset)"
            severity failure;
        assert REG_OMNI_SP67_C - REG_OMNI_SP01_C = 3
            report "omni_engine: OMNI_SP01 .. OMNI_SP67 are not consecutive"
            severity failure;
        assert REG_OMNI_CNT_PARAM_RX_C - REG_OMNI_CNT_FB_RX_C = cnt_num_c - 1
            report "omni_engine: OMNI_CNT_FB_RX .. OMNI_CNT_PARAM_RX are not consecutive"
            severity failure;
        assert false
            report "omni_engine: " & integer'image(N_SLOTS) & " slots, master id "
                   & integer'image(MASTER_ID_DEFAULT)
            severity note;
        return true;

    end function check_config;

    constant config_ok_c : boolean := check_config;

    -- ---------------------------------------------------------------------------------------------
    -- Types
    -- ---------------------------------------------------------------------------------------------

    type sp_arr_t is array (0 to max_axes_c - 1) of std_logic_vector(15 downto 0);

    type inc_arr_t is array (0 to cnt_num_c - 1) of natural range 0 to 2 ** inc_w_c - 1;

    type tx_state_t is (
        S_IDLE, -- the highest-priority due item starts a frame
        S_WAIT  -- tx_req_o = 1 until tx_ack_i
    );

    type kind_t is (
        K_STOP,  -- NMT stop all after a missing node (STOP_ON_MISSING)
        K_NMT,   -- host NMT
        K_BC,    -- broadcast after an Omni SYNC
        K_QUERY, -- node query
        K_REPLY, -- reply to another node's query
        K_PARAM  -- parameter frame
    );

    type rx_state_t is (
        S_RX_IDLE,  -- waiting for rx_valid_i
        S_RX_MATCH, -- frame registered, classified
        S_RX_REPLY  -- query received: waiting until the reply (or another frame) is presented
    );

    -- ---------------------------------------------------------------------------------------------
    -- Helpers (is_off, keep_bytes, bit_int, sat_add, put: canopen_util_pkg)
    -- ---------------------------------------------------------------------------------------------

    -- the last value of a modulo-n count: n - 1, and 0 for n = 0 (acts as 1)

    function last_of (n : unsigned(15 downto 0)) return unsigned is
    begin

        if n = 0 then
            return to_unsigned(0, 16);
        end if;

        return n - 1;

    end function last_of;

    -- ---------------------------------------------------------------------------------------------
    -- Configuration (host)
    -- ---------------------------------------------------------------------------------------------
    -- OMNI_CFG fields
    signal master_id : std_logic_vector(7 downto 0);
    signal n_axes    : std_logic_vector(3 downto 0);
    signal bc4x2     : std_logic;
    signal sender    : std_logic;
    signal sync_mode : std_logic;
    signal stop_miss : std_logic;
    -- K, M, query window [us]
    signal k_reg : unsigned(15 downto 0);
    signal m_reg : unsigned(15 downto 0);
    -- K - 1 and M - 1 (16 bits, 0 for K, M <= 1), registered with K and M: the cycle-instant
    -- wrap compares kmod / pmod with a register, no subtractor in the path
    signal k_last   : unsigned(15 downto 0);
    signal m_last   : unsigned(15 downto 0);
    signal qwin_reg : unsigned(15 downto 0);
    -- N_AXES out of range for the layout
    signal cfg_err : std_logic;

    -- ---------------------------------------------------------------------------------------------
    -- Set-points: staging (host), committed (COMMIT), the cycle frame built from them
    -- ---------------------------------------------------------------------------------------------
    signal staging : sp_arr_t;
    -- the set of the last COMMIT (the set the next take sends); PENDING: a commit not yet taken
    signal com_set : sp_arr_t;
    signal pending : std_logic;
    -- broadcast id and DLC of the configuration registers (feasibility, the frame builder)
    signal bc_id  : std_logic_vector(10 downto 0);
    signal bc_dlc : std_logic_vector(3 downto 0);
    -- frame builder: rebuilds the broadcast frame from com_set and the configuration one byte
    -- per cycle after a COMMIT or an OMNI_CFG write (restarts on a new one); the finished frame
    -- is copied into frm_* in one edge; b_run = 0: frm_* is the frame of the current com_set
    -- and configuration
    signal b_run    : std_logic;
    signal b_byte   : natural range 0 to 8;
    signal b_data   : std_logic_vector(63 downto 0);
    signal b_next   : std_logic_vector(7 downto 0);
    signal frm_id   : std_logic_vector(10 downto 0);
    signal frm_dlc  : std_logic_vector(3 downto 0);
    signal frm_data : std_logic_vector(63 downto 0);
    -- the next cycle frame is the Omni SYNC
    signal sync_now : std_logic;

    -- ---------------------------------------------------------------------------------------------
    -- Cycle bookkeeping
    -- ---------------------------------------------------------------------------------------------
    -- enable_i of the previous cycle; cycle_i strobes since enable (CYCLE); k mod K and k mod M of
    -- the next cycle k; a cycle_i was seen since enable; the last take loaded the Omni SYNC
    signal en_q       : std_logic;
    signal cyc_cnt    : unsigned(15 downto 0);
    signal kmod       : unsigned(15 downto 0);
    signal pmod       : unsigned(15 downto 0);
    signal first_seen : std_logic;
    signal took_sync  : std_logic;
    -- broadcast to send after the SYNC (latched at the SYNC take)
    signal bcq_dlc  : std_logic_vector(3 downto 0);
    signal bcq_data : std_logic_vector(63 downto 0);
    signal bcq_id   : std_logic_vector(10 downto 0);

    -- ---------------------------------------------------------------------------------------------
    -- Frame queue
    -- ---------------------------------------------------------------------------------------------
    signal stop_due  : std_logic;
    signal nmt_due   : std_logic;
    signal bc_due    : std_logic;
    signal query_due : std_logic;
    signal reply_due : std_logic;
    signal par_due   : std_logic;
    -- host NMT frame
    signal nmt_node  : std_logic_vector(7 downto 0);
    signal nmt_state : std_logic;
    -- parameter frame registers
    signal par_node : std_logic_vector(7 downto 0);
    signal par_type : std_logic_vector(7 downto 0);
    signal par_dlc  : std_logic_vector(3 downto 0);
    signal par_lo   : std_logic_vector(31 downto 0);
    signal par_hi   : std_logic_vector(15 downto 0);
    -- transmitter: state, kind of the frame on tx_req_o, the item starting now
    signal tx_st   : tx_state_t;
    signal tx_kind : kind_t;
    signal start   : std_logic;
    signal st_kind : kind_t;
    -- frame registers
    signal tx_req  : std_logic;
    signal tx_id   : std_logic_vector(10 downto 0);
    signal tx_rtr  : std_logic;
    signal tx_dlc  : std_logic_vector(3 downto 0);
    signal tx_data : std_logic_vector(63 downto 0);

    -- ---------------------------------------------------------------------------------------------
    -- Node table (omni_node_table) and query window
    -- ---------------------------------------------------------------------------------------------
    -- node table: hand-over strobe, the cycle closing while running and
    -- its missed-cycle check, the slot search registered with the frame, slots missed at the
    -- close and after the query window, its part of the read data, the slots for feasibility
    signal nt_hand      : std_logic;
    signal nt_close     : std_logic;
    signal nt_check     : std_logic;
    signal nt_fb_hit    : std_logic;
    signal nt_dlc_ok    : std_logic;
    signal nt_rep_hit   : std_logic;
    signal nt_miss_cnt  : std_logic_vector(3 downto 0);
    signal nt_qmiss_any : std_logic;
    signal nt_qmiss_cnt : std_logic_vector(3 downto 0);
    signal nt_rd_word   : std_logic_vector(31 downto 0);
    signal s_valid      : std_logic_vector(N_SLOTS - 1 downto 0);
    signal s_dlc_vec    : std_logic_vector(4 * N_SLOTS - 1 downto 0);
    -- query: window open, us left, evaluation due; the query's tx_ack_i (window start)
    signal q_open  : std_logic;
    signal q_cnt   : unsigned(15 downto 0);
    signal q_eval  : std_logic;
    signal q_start : std_logic;
    -- parameter mailbox
    signal pmb_sender : std_logic_vector(7 downto 0);
    signal pmb_type   : std_logic_vector(7 downto 0);
    signal pmb_dlc    : std_logic_vector(3 downto 0);
    signal pmb_lo     : std_logic_vector(31 downto 0);
    signal pmb_hi     : std_logic_vector(15 downto 0);
    signal pmb_new    : std_logic;
    signal pmb_ovr    : std_logic;
    -- a parameter frame was ever stored: until then the mailbox reads 0 (its data registers
    -- have no reset)
    signal pmb_any : std_logic;

    -- ---------------------------------------------------------------------------------------------
    -- Receiver
    -- ---------------------------------------------------------------------------------------------
    signal rx_st : rx_state_t;
    -- classes in S_RX_MATCH (enabled only)
    signal c_store : std_logic;
    signal c_len   : std_logic;
    signal c_query : std_logic;
    signal c_reply : std_logic;
    signal c_param : std_logic;
    signal c_unexp : std_logic;
    -- strobes
    signal rx_done_q  : std_logic;
    signal rx_reply_q : std_logic;
    signal rx_unexp_q : std_logic;
    signal ev_q       : std_logic;

    -- ---------------------------------------------------------------------------------------------
    -- Feasibility (omni_feasibility: worst-case bits of one cycle, the cycle fits the period)
    -- ---------------------------------------------------------------------------------------------
    signal f_bits   : std_logic_vector(15 downto 0);
    signal feasible : std_logic;

    -- ---------------------------------------------------------------------------------------------
    -- Host window
    -- ---------------------------------------------------------------------------------------------
    signal wr_cfg   : std_logic;
    signal wr_ctrl  : std_logic;
    signal wr_k     : std_logic;
    signal wr_poll  : std_logic;
    signal wr_qwin  : std_logic;
    signal wr_nmt   : std_logic;
    signal wr_phdr  : std_logic;
    signal wr_plo   : std_logic;
    signal wr_phi   : std_logic;
    signal wr_sel   : std_logic;
    signal wr_scfg  : std_logic;
    signal wr_fbnew : std_logic;
    signal wr_miss  : std_logic;
    signal wr_pmbi  : std_logic;
    signal wr_sp    : std_logic_vector(3 downto 0);
    -- OMNI_CTRL pulses
    signal commit : std_logic;
    signal p_send : std_logic;
    signal clr    : std_logic;
    -- read multiplexer and its register; counters
    signal rd_mux  : std_logic_vector(31 downto 0);
    signal rdata_q : std_logic_vector(31 downto 0);
    -- counters (canopen_counter_bank): amounts of the events of the previous cycle, read
    -- address, the registered read is a counter, its read data
    signal cnt_inc   : std_logic_vector(cnt_num_c * inc_w_c - 1 downto 0);
    signal cnt_ra    : std_logic_vector(3 downto 0);
    signal cnt_sel_q : std_logic;
    signal cnt_q     : std_logic_vector(31 downto 0);

begin

    -- ---------------------------------------------------------------------------------------------
    -- Host write decode
    -- ---------------------------------------------------------------------------------------------
    wr_cfg   <= reg_we_i when is_off(reg_addr_i, off_cfg_c) else '0';
    wr_ctrl  <= reg_we_i when is_off(reg_addr_i, off_ctrl_c) else '0';
    wr_k     <= reg_we_i when is_off(reg_addr_i, off_k_c) else '0';
    wr_poll  <= reg_we_i when is_off(reg_addr_i, off_poll_c) else '0';
    wr_qwin  <= reg_we_i when is_off(reg_addr_i, off_qwin_c) else '0';
    wr_nmt   <= reg_we_i when is_off(reg_addr_i, off_nmt_c) else '0';
    wr_phdr  <= reg_we_i when is_off(reg_addr_i, off_phdr_c) else '0';
    wr_plo   <= reg_we_i when is_off(reg_addr_i, off_plo_c) else '0';
    wr_phi   <= reg_we_i when is_off(reg_addr_i, off_phi_c) else '0';
    wr_sel   <= reg_we_i when is_off(reg_addr_i, off_sel_c) else '0';
    wr_scfg  <= reg_we_i when is_off(reg_addr_i, off_scfg_c) else '0';
    wr_fbnew <= reg_we_i when is_off(reg_addr_i, off_fbnew_c) else '0';
    wr_miss  <= reg_we_i when is_off(reg_addr_i, off_miss_c) else '0';
    wr_pmbi  <= reg_we_i when is_off(reg_addr_i, off_pmbi_c) else '0';

    sp_dec_gen : for i in 0 to 3 generate
        wr_sp(i) <= reg_we_i when is_off(reg_addr_i, off_sp_c + i) else '0';
    end generate sp_dec_gen;

    commit <= wr_ctrl and reg_wdata_i(OMNI_CTRL_COMMIT_C);
    p_send <= wr_ctrl and reg_wdata_i(OMNI_CTRL_PARAM_SEND_C);
    clr    <= wr_ctrl and reg_wdata_i(OMNI_CTRL_CLR_COUNTERS_C);

    -- ---------------------------------------------------------------------------------------------
    -- Cycle frame (a function of registers only: what the core copies at cyc_take_i is what the
    -- engine records at the same edge)
    -- ---------------------------------------------------------------------------------------------
    frame_proc : process (bc4x2, kmod, master_id, n_axes, sender, sync_mode) is

        variable n_v : natural range 0 to 15;

    begin

        n_v := to_integer(unsigned(n_axes));

        if n_v = 0 or (bc4x2 = '1' and n_v > 4) or (bc4x2 = '0' and n_v + bit_int(sender) > 8) then
            cfg_err <= '1';
        else
            cfg_err <= '0';
        end if;

        if bc4x2 = '1' then
            bc_id  <= fc_bc4_c & master_id;
            bc_dlc <= std_logic_vector(shift_left(unsigned(n_axes), 1));
        else
            bc_id  <= fc_bc8_c & master_id;
            bc_dlc <= std_logic_vector(unsigned(n_axes) + bit_int(sender));
        end if;

        if sync_mode = '1' and kmod = 0 then
            sync_now <= '1';
        else
            sync_now <= '0';
        end if;

    end process frame_proc;

    -- byte b_byte of the broadcast data (A1): [sender]? then the axes, highest first; 1 byte
    -- (low 8 bits) per axis, or 2 bytes big-endian per axis (BCAST_4X2); 0 from the DLC on and
    -- where the layout names no axis (CFG_ERR). One 8:1 multiplexer of 16 bits for all bytes.
    byte_proc : process (b_byte, bc4x2, bc_dlc, com_set, master_id, n_axes, sender) is

        variable j_v   : natural range 0 to 8;
        variable a_v   : integer range -9 to 15;
        variable w_v   : std_logic_vector(15 downto 0);
        variable hi_v  : boolean;
        variable mid_v : boolean;

    begin

        j_v   := b_byte;
        mid_v := bc4x2 = '0' and sender = '1' and j_v = 0;

        if bc4x2 = '1' then
            -- axis n - 1 - j / 2: high byte at even j, low byte at odd j
            a_v  := to_integer(unsigned(n_axes)) - 1 - j_v / 2;
            hi_v := j_v mod 2 = 0;
        else
            -- axis n - 1 + s - j
            a_v  := to_integer(unsigned(n_axes)) - 1 + bit_int(sender) - j_v;
            hi_v := false;
        end if;

        w_v := (others => '0');

        for a in 0 to max_axes_c - 1 loop

            if a_v mod 8 = a then
                w_v := com_set(a);
            end if;

        end loop;

        if j_v >= to_integer(unsigned(bc_dlc)) or j_v > 7 then
            b_next <= (others => '0');
        elsif mid_v then
            b_next <= master_id;
        elsif a_v < 0 or a_v >= max_axes_c then
            b_next <= (others => '0');
        elsif hi_v then
            b_next <= w_v(15 downto 8);
        else
            b_next <= w_v(7 downto 0);
        end if;

    end process byte_proc;

    -- the builder: b_byte 0..7 writes b_data, b_byte 8 copies the frame; a COMMIT or an
    -- OMNI_CFG write (re)starts it at byte 0 from the next edge (com_set and the configuration
    -- registers take the new values at that edge)
    build_proc : process (clk_i, rst_n_i) is
    begin

        if rst_n_i = '0' then
            b_run    <= '0';
            b_byte   <= 0;
            b_data   <= (others => '0');
            frm_id   <= fc_bc8_c & std_logic_vector(to_unsigned(MASTER_ID_DEFAULT, 8));
            frm_dlc  <= (others => '0');
            frm_data <= (others => '0');
        elsif rising_edge(clk_i) then
            if commit = '1' or wr_cfg = '1' then
                b_run  <= '1';
                b_byte <= 0;
            elsif b_run = '1' then
                if b_byte = 8 then
                    frm_id   <= bc_id;
                    frm_dlc  <= bc_dlc;
                    frm_data <= b_data;
                    b_run    <= '0';
                    b_byte   <= 0;
                else
                    b_byte <= b_byte + 1;

                    for j in 0 to 7 loop

                        if b_byte = j then
                            b_data(8 * j + 7 downto 8 * j) <= b_next;
                        end if;

                    end loop;

                end if;
            end if;
        end if;

    end process build_proc;

    cyc_id_o   <= sync_id_c when sync_now = '1' else frm_id;
    cyc_dlc_o  <= (others => '0') when sync_now = '1' else frm_dlc;
    cyc_data_o <= (others => '0') when sync_now = '1' else frm_data;

    -- ---------------------------------------------------------------------------------------------
    -- Transmit priority (A11, docs): stop all, NMT, broadcast after SYNC, query, reply, parameter
    -- ---------------------------------------------------------------------------------------------
    pick_proc : process (bc_due, enable_i, nmt_due, par_due, query_due, reply_due, stop_due,
                         tx_st) is
    begin

        start   <= '0';
        st_kind <= K_PARAM;

        if tx_st = S_IDLE and enable_i = '1' then
            if stop_due = '1' then
                start   <= '1';
                st_kind <= K_STOP;
            elsif nmt_due = '1' then
                start   <= '1';
                st_kind <= K_NMT;
            elsif bc_due = '1' then
                start   <= '1';
                st_kind <= K_BC;
            elsif query_due = '1' then
                start   <= '1';
                st_kind <= K_QUERY;
            elsif reply_due = '1' then
                start   <= '1';
                st_kind <= K_REPLY;
            elsif par_due = '1' then
                start   <= '1';
                st_kind <= K_PARAM;
            end if;
        end if;

    end process pick_proc;

    -- ---------------------------------------------------------------------------------------------
    -- Receive classification
    -- ---------------------------------------------------------------------------------------------
    -- the node table searches its slots at the hand-over (registered with the frame) and
    -- compares the matched slot's DLC in the match cycle
    match_proc : process (enable_i, master_id, nt_dlc_ok, nt_fb_hit, nt_rep_hit, rx_dlc_i, rx_id_i,
                          rx_rtr_i, rx_st) is

        variable fc_v   : std_logic_vector(2 downto 0);
        variable node_v : std_logic_vector(7 downto 0);
        variable pd_v   : boolean;

    begin

        fc_v   := rx_id_i(10 downto 8);
        node_v := rx_id_i(7 downto 0);
        pd_v   := fc_v = "010" or fc_v = "011" or fc_v = "101" or fc_v = "110";

        c_store <= '0';
        c_len   <= '0';
        c_query <= '0';
        c_reply <= '0';
        c_param <= '0';
        c_unexp <= '0';

        if rx_st = S_RX_MATCH and enable_i = '1' then
            if rx_rtr_i = '1' then
                if rx_id_i = "000" & x"00" then
                    c_query <= '1';
                elsif fc_v = fc_nmt_c and nt_rep_hit = '1' then
                    c_reply <= '1';
                else
                    c_unexp <= '1';
                end if;
            elsif pd_v and node_v = master_id and rx_dlc_i /= x"0" and nt_fb_hit = '1' then
                if nt_dlc_ok = '1' then
                    c_store <= '1';
                else
                    c_len <= '1';
                end if;
            elsif fc_v = fc_param_c and node_v = master_id
                  and unsigned(rx_dlc_i) >= param_min_c then
                c_param <= '1';
            else
                c_unexp <= '1';
            end if;
        end if;

    end process match_proc;

    -- ---------------------------------------------------------------------------------------------
    -- Configuration registers and staging set-points (host writes)
    -- ---------------------------------------------------------------------------------------------
    cfg_proc : process (clk_i, rst_n_i) is
    begin

        if rst_n_i = '0' then
            master_id <= std_logic_vector(to_unsigned(MASTER_ID_DEFAULT, 8));
            n_axes    <= (others => '0');
            bc4x2     <= '0';
            sender    <= '0';
            sync_mode <= '0';
            stop_miss <= '0';
            k_reg     <= unsigned(OMNI_SYNC_K_RESET_C(15 downto 0));
            k_last    <= last_of(unsigned(OMNI_SYNC_K_RESET_C(15 downto 0)));
            m_reg     <= (others => '0');
            m_last    <= (others => '0');
            qwin_reg  <= unsigned(OMNI_QUERY_WIN_RESET_C(15 downto 0));
            staging   <= (others => (others => '0'));
        elsif rising_edge(clk_i) then
            if wr_cfg = '1' then
                master_id <= reg_wdata_i(OMNI_CFG_MASTER_ID_HI_C downto OMNI_CFG_MASTER_ID_LO_C);
                n_axes    <= reg_wdata_i(OMNI_CFG_N_AXES_HI_C downto OMNI_CFG_N_AXES_LO_C);
                bc4x2     <= reg_wdata_i(OMNI_CFG_BCAST_4X2_C);
                sender    <= reg_wdata_i(OMNI_CFG_SENDER_C);
                sync_mode <= reg_wdata_i(OMNI_CFG_SYNC_MODE_C);
                stop_miss <= reg_wdata_i(OMNI_CFG_STOP_ON_MISSING_C);
            end if;
            if wr_k = '1' then
                k_reg  <= unsigned(reg_wdata_i(OMNI_SYNC_K_K_HI_C downto OMNI_SYNC_K_K_LO_C));
                k_last <= last_of(unsigned(reg_wdata_i(OMNI_SYNC_K_K_HI_C downto
                                                       OMNI_SYNC_K_K_LO_C)));
            end if;
            if wr_poll = '1' then
                m_reg  <= unsigned(reg_wdata_i(OMNI_POLL_M_HI_C downto OMNI_POLL_M_LO_C));
                m_last <= last_of(unsigned(reg_wdata_i(OMNI_POLL_M_HI_C downto
                                                       OMNI_POLL_M_LO_C)));
            end if;
            if wr_qwin = '1' then
                qwin_reg <= unsigned(reg_wdata_i(OMNI_QUERY_WIN_US_HI_C downto
                                                 OMNI_QUERY_WIN_US_LO_C));
            end if;

            for i in 0 to 3 loop

                if wr_sp(i) = '1' then
                    staging(2 * i)     <= reg_wdata_i(OMNI_SP01_AXIS0_HI_C downto
                                                      OMNI_SP01_AXIS0_LO_C);
                    staging(2 * i + 1) <= reg_wdata_i(OMNI_SP01_AXIS1_HI_C downto
                                                      OMNI_SP01_AXIS1_LO_C);
                end if;

            end loop;

        end if;

    end process cfg_proc;

    -- ---------------------------------------------------------------------------------------------
    -- Control: set-points, cycle, queue, transmitter, receiver, node table
    -- ---------------------------------------------------------------------------------------------
    ctrl_proc : process (clk_i, rst_n_i) is

        variable pend_v    : std_logic;
        variable ts_v      : std_logic;
        variable inc_v     : inc_arr_t;
        variable amt_v     : unsigned(inc_w_c - 1 downto 0);
        variable run_v     : boolean;
        variable fire_sync : boolean;
        variable poll_now  : boolean;
        variable bd_v      : std_logic;
        variable qd_v      : std_logic;
        variable rd_v      : std_logic;
        variable sd_v      : std_logic;
        variable nd_v      : std_logic;
        variable pd_v      : std_logic;

    begin

        if rst_n_i = '0' then
            com_set    <= (others => (others => '0'));
            pending    <= '0';
            en_q       <= '0';
            cyc_cnt    <= (others => '0');
            kmod       <= (others => '0');
            pmod       <= (others => '0');
            first_seen <= '0';
            took_sync  <= '0';
            stop_due   <= '0';
            nmt_due    <= '0';
            bc_due     <= '0';
            query_due  <= '0';
            reply_due  <= '0';
            par_due    <= '0';
            nmt_node   <= (others => '0');
            nmt_state  <= '0';
            par_node   <= (others => '0');
            par_type   <= (others => '0');
            par_dlc    <= (others => '0');
            par_lo     <= (others => '0');
            par_hi     <= (others => '0');
            tx_st      <= S_IDLE;
            tx_kind    <= K_PARAM;
            tx_req     <= '0';
            q_open     <= '0';
            q_cnt      <= (others => '0');
            q_eval     <= '0';
            pmb_new    <= '0';
            pmb_ovr    <= '0';
            pmb_any    <= '0';
            rx_st      <= S_RX_IDLE;
            rx_done_q  <= '0';
            rx_reply_q <= '0';
            rx_unexp_q <= '0';
            ev_q       <= '0';
            cnt_inc    <= (others => '0');
        elsif rising_edge(clk_i) then
            inc_v      := (others => 0);
            rx_done_q  <= '0';
            rx_reply_q <= '0';
            rx_unexp_q <= '0';
            ev_q       <= '0';
            en_q       <= enable_i;
            run_v      := enable_i = '1';

            -- ------------------------------------------------------- set-points and cycle frame
            -- a take activates the pending set (the take happens before a fire in the same cycle)
            pend_v := pending;
            ts_v   := took_sync;
            -- (the pending set is taken only when the builder has finished its frame: b_run = 0)
            if cyc_take_i = '1' and run_v then
                if b_run = '0' then
                    pend_v := '0';
                end if;
                ts_v := sync_now;
            end if;
            if commit = '1' then
                com_set <= staging;
                pend_v  := '1';
            end if;
            pending <= pend_v;

            -- ------------------------------------------------------------------- cycle instant
            fire_sync := false;
            poll_now  := false;
            if not run_v then
                cyc_cnt    <= (others => '0');
                kmod       <= (others => '0');
                pmod       <= (others => '0');
                first_seen <= '0';
                ts_v       := '0';
            elsif en_q = '0' then
                -- enable rose: count from the first cycle_i after it
                cyc_cnt    <= (others => '0');
                kmod       <= (others => '0');
                pmod       <= (others => '0');
                first_seen <= '0';
            elsif cycle_i = '1' then
                cyc_cnt    <= cyc_cnt + 1;
                first_seen <= '1';
                if kmod >= k_last then
                    kmod <= (others => '0');
                else
                    kmod <= kmod + 1;
                end if;
                if pmod >= m_last then
                    pmod <= (others => '0');
                else
                    pmod <= pmod + 1;
                end if;
                fire_sync := ts_v = '1';
                poll_now  := m_reg /= 0 and pmod = 0;
                ts_v      := '0';
            end if;
            took_sync <= ts_v;

            -- ------------------------------------------------------------------------- queue
            -- the item starting now leaves the queue; requests made at this edge are kept
            bd_v := bc_due;
            qd_v := query_due;
            rd_v := reply_due;
            sd_v := stop_due;
            nd_v := nmt_due;
            pd_v := par_due;
            if start = '1' then

                case st_kind is

                    when K_STOP =>

                        sd_v := '0';

                    when K_NMT =>

                        nd_v := '0';

                    when K_BC =>

                        bd_v := '0';

                    when K_QUERY =>

                        qd_v := '0';

                    when K_REPLY =>

                        rd_v := '0';

                    when K_PARAM =>

                        pd_v := '0';

                end case;

            end if;
            if fire_sync then
                -- the cycle frame fired now was the Omni SYNC: the broadcast follows
                if bd_v = '1' then
                    inc_v(cnt_late_c) := inc_v(cnt_late_c) + 1;
                end if;
                bd_v := '1';
            end if;
            if poll_now then
                -- node query every M cycles, unless the previous one is still running
                if query_due = '1' or q_open = '1' or q_eval = '1'
                   or (tx_req = '1' and tx_kind = K_QUERY) then
                    inc_v(cnt_late_c) := inc_v(cnt_late_c) + 1;
                else
                    qd_v := '1';
                end if;
            end if;
            if c_query = '1' then
                rd_v := '1';
            end if;
            if q_eval = '1' and stop_miss = '1' and nt_qmiss_any = '1' then
                sd_v := '1';
            end if;
            if wr_nmt = '1' and run_v then
                if nd_v = '1' then
                    inc_v(cnt_refuse_c) := 1;
                else
                    nd_v      := '1';
                    nmt_node  <= reg_wdata_i(OMNI_NMT_NODE_HI_C downto OMNI_NMT_NODE_LO_C);
                    nmt_state <= reg_wdata_i(OMNI_NMT_STATE_C);
                end if;
            end if;
            if p_send = '1' and run_v then
                if pd_v = '1' then
                    inc_v(cnt_refuse_c) := 1;
                else
                    pd_v := '1';
                end if;
            end if;
            if not run_v then
                bd_v := '0';
                qd_v := '0';
                rd_v := '0';
                sd_v := '0';
                nd_v := '0';
                pd_v := '0';
            end if;
            bc_due    <= bd_v;
            query_due <= qd_v;
            reply_due <= rd_v;
            stop_due  <= sd_v;
            nmt_due   <= nd_v;
            par_due   <= pd_v;
            if not run_v and (wr_nmt = '1' or p_send = '1') then
                inc_v(cnt_refuse_c) := 1;
            end if;

            -- parameter registers (refused while the frame is queued)
            if par_due = '0' then
                if wr_phdr = '1' then
                    par_node <= reg_wdata_i(OMNI_PARAM_HDR_NODE_HI_C downto
                                            OMNI_PARAM_HDR_NODE_LO_C);
                    par_type <= reg_wdata_i(OMNI_PARAM_HDR_TYPE_HI_C downto
                                            OMNI_PARAM_HDR_TYPE_LO_C);
                    par_dlc  <= reg_wdata_i(OMNI_PARAM_HDR_DLC_HI_C downto
                                            OMNI_PARAM_HDR_DLC_LO_C);
                end if;
                if wr_plo = '1' then
                    par_lo <= reg_wdata_i(OMNI_PARAM_LO_DATA_HI_C downto OMNI_PARAM_LO_DATA_LO_C);
                end if;
                if wr_phi = '1' then
                    par_hi <= reg_wdata_i(OMNI_PARAM_HI_DATA_HI_C downto OMNI_PARAM_HI_DATA_LO_C);
                end if;
            elsif wr_phdr = '1' or wr_plo = '1' or wr_phi = '1' then
                inc_v(cnt_refuse_c) := 1;
            end if;

            -- ------------------------------------------------------------------- transmitter

            case tx_st is

                when S_IDLE =>

                    if start = '1' then
                        tx_kind <= st_kind;
                        tx_req  <= '1';
                        tx_st   <= S_WAIT;
                    end if;

                when S_WAIT =>

                    if tx_ack_i = '1' or not run_v then
                        tx_req <= '0';
                        tx_st  <= S_IDLE;
                    end if;

            end case;

            if tx_st = S_WAIT and tx_ack_i = '1' and run_v then
                inc_v(cnt_tx_c) := 1;
            end if;

            -- ----------------------------------------------------------------- query window
            q_eval <= '0';
            if not run_v then
                q_open <= '0';
            elsif q_start = '1' then
                -- the window starts at the query's tx_ack_i (a tick at this edge is not counted;
                -- the node table clears ALIVE)
                q_open <= '1';
                if qwin_reg = 0 then
                    q_cnt <= to_unsigned(1, 16);
                else
                    q_cnt <= qwin_reg;
                end if;
            elsif q_open = '1' and tick_us_i = '1' then
                if q_cnt <= 1 then
                    q_open <= '0';
                    q_eval <= '1';
                else
                    q_cnt <= q_cnt - 1;
                end if;
            end if;

            if q_eval = '1' then
                if nt_qmiss_any = '1' then
                    ev_q <= '1';
                end if;
                inc_v(cnt_nmiss_c) := to_integer(unsigned(nt_qmiss_cnt));
            end if;

            -- --------------------------------------------------------------------- receiver

            case rx_st is

                when S_RX_IDLE =>

                    if rx_valid_i = '1' then
                        rx_st <= S_RX_MATCH;
                    end if;

                when S_RX_MATCH =>

                    if c_query = '1' then
                        rx_st <= S_RX_REPLY;
                    else
                        rx_done_q  <= '1';
                        rx_unexp_q <= c_unexp;
                        rx_st      <= S_RX_IDLE;
                    end if;

                when S_RX_REPLY =>

                    -- done as soon as a frame is presented (the reply, or one before it: the
                    -- reply then follows through FSM T20)
                    if not run_v then
                        rx_done_q <= '1';
                        rx_st     <= S_RX_IDLE;
                    elsif tx_req = '1' then
                        rx_done_q <= '1';
                        rx_st     <= S_RX_IDLE;
                        if tx_kind = K_REPLY and tx_ack_i = '0' then
                            rx_reply_q <= '1';
                        end if;
                    end if;

            end case;

            if c_store = '1' or c_param = '1' then
                ev_q <= '1';
            end if;
            if c_store = '1' then
                inc_v(cnt_fb_c) := 1;
            end if;
            if c_len = '1' then
                inc_v(cnt_len_c) := 1;
            end if;
            if c_unexp = '1' then
                inc_v(cnt_unexp_c) := 1;
            end if;
            if c_param = '1' then
                inc_v(cnt_prx_c) := 1;
            end if;

            -- parameter mailbox
            if wr_pmbi = '1' then
                if reg_wdata_i(OMNI_PMB_INFO_NEW_C) = '1' then
                    pmb_new <= '0';
                end if;
                if reg_wdata_i(OMNI_PMB_INFO_OVERRUN_C) = '1' then
                    pmb_ovr <= '0';
                end if;
            end if;
            if c_param = '1' then
                pmb_new <= '1';
                pmb_any <= '1';
                if pmb_new = '1' and not (wr_pmbi = '1'
                                          and reg_wdata_i(OMNI_PMB_INFO_NEW_C) = '1') then
                    pmb_ovr <= '1';
                end if;
            end if;

            -- ------------------------------------------------------------------- node table
            inc_v(cnt_miss_c) := to_integer(unsigned(nt_miss_cnt));

            -- -------------------------------------------------------------------- counters

            -- amounts to the counter bank, one cycle later; a clear drops the events of its
            -- own cycle (the bank drops the amounts presented in the clear cycle)
            for i in 0 to cnt_num_c - 1 loop

                amt_v := to_unsigned(inc_v(i), inc_w_c);
                if clr = '1' then
                    amt_v := (others => '0');
                end if;
                cnt_inc(inc_w_c * i + inc_w_c - 1 downto inc_w_c * i) <= std_logic_vector(amt_v);

            end loop;

        end if;

    end process ctrl_proc;

    -- ---------------------------------------------------------------------------------------------
    -- Datapath registers qualified by a flag (no reset)
    -- ---------------------------------------------------------------------------------------------
    data_proc : process (clk_i) is

        variable d_v : std_logic_vector(63 downto 0);

    begin

        if rising_edge(clk_i) then
            -- broadcast of a SYNC cycle, latched at its take
            if cyc_take_i = '1' and sync_now = '1' then
                bcq_id   <= frm_id;
                bcq_dlc  <= frm_dlc;
                bcq_data <= frm_data;
            end if;

            -- the frame starting now
            if start = '1' then

                case st_kind is

                    when K_STOP =>

                        tx_id   <= (others => '0');
                        tx_rtr  <= '0';
                        tx_dlc  <= nmt_dlc_c;
                        tx_data <= (others => '0');

                    when K_NMT =>

                        tx_id   <= (others => '0');
                        tx_rtr  <= '0';
                        tx_dlc  <= nmt_dlc_c;
                        tx_data <= std_logic_vector(resize(unsigned(nmt_state & nmt_node), 64));

                    when K_BC =>

                        tx_id   <= bcq_id;
                        tx_rtr  <= '0';
                        tx_dlc  <= bcq_dlc;
                        tx_data <= bcq_data;

                    when K_QUERY =>

                        tx_id   <= (others => '0');
                        tx_rtr  <= '1';
                        tx_dlc  <= (others => '0');
                        tx_data <= (others => '0');

                    when K_REPLY =>

                        tx_id   <= fc_nmt_c & master_id;
                        tx_rtr  <= '1';
                        tx_dlc  <= (others => '0');
                        tx_data <= (others => '0');

                    when K_PARAM =>

                        tx_id   <= fc_param_c & par_node;
                        tx_rtr  <= '0';
                        tx_dlc  <= par_dlc;
                        tx_data <= keep_bytes(par_hi & par_lo & par_type & master_id, par_dlc);

                end case;

            end if;

            -- parameter mailbox
            if c_param = '1' then
                pmb_sender <= rx_data_i(7 downto 0);
                pmb_type   <= rx_data_i(15 downto 8);
                pmb_dlc    <= rx_dlc_i;
                d_v        := keep_bytes(rx_data_i, rx_dlc_i);
                pmb_lo     <= d_v(47 downto 16);
                pmb_hi     <= d_v(63 downto 48);
            end if;
        end if;

    end process data_proc;

    -- ---------------------------------------------------------------------------------------------
    -- Node table: slots, slot search, feedback RAM, slot counters, flags (omni_node_table)
    -- ---------------------------------------------------------------------------------------------
    nt_hand  <= '1' when rx_st = S_RX_IDLE and rx_valid_i = '1' else
                '0';
    nt_close <= cycle_i and enable_i and en_q;
    nt_check <= nt_close and first_seen;
    q_start  <= '1' when enable_i = '1' and tx_st = S_WAIT and tx_ack_i = '1'
                         and tx_kind = K_QUERY else
                '0';

    node_table_inst : entity work.omni_node_table
        generic map (
            N_SLOTS => N_SLOTS
        )
        port map (
            clk_i         => clk_i,
            rst_n_i       => rst_n_i,
            wr_sel_i      => wr_sel,
            wr_scfg_i     => wr_scfg,
            wr_fbnew_i    => wr_fbnew,
            wr_miss_i     => wr_miss,
            wdata_i       => reg_wdata_i,
            clr_i         => clr,
            reg_addr_i    => reg_addr_i,
            rd_word_o     => nt_rd_word,
            cycle_close_i => nt_close,
            cycle_check_i => nt_check,
            cyc_cnt_i     => std_logic_vector(cyc_cnt),
            miss_cnt_o    => nt_miss_cnt,
            hand_i        => nt_hand,
            rx_id_i       => rx_id_i,
            rx_dlc_i      => rx_dlc_i,
            rx_data_i     => rx_data_i,
            fb_hit_o      => nt_fb_hit,
            fb_dlc_ok_o   => nt_dlc_ok,
            rep_hit_o     => nt_rep_hit,
            store_i       => c_store,
            len_err_i     => c_len,
            reply_i       => c_reply,
            q_start_i     => q_start,
            q_open_i      => q_open,
            q_eval_i      => q_eval,
            qmiss_any_o   => nt_qmiss_any,
            qmiss_cnt_o   => nt_qmiss_cnt,
            slot_valid_o  => s_valid,
            slot_dlc_o    => s_dlc_vec
        );

    -- ---------------------------------------------------------------------------------------------
    -- Feasibility: worst-case bits of one cycle against the period (omni_feasibility)
    -- ---------------------------------------------------------------------------------------------

    feas_inst : entity work.omni_feasibility
        generic map (
            N_SLOTS     => N_SLOTS,
            BITRATE_BPS => BITRATE_BPS
        )
        port map (
            clk_i        => clk_i,
            rst_n_i      => rst_n_i,
            bc_dlc_i     => bc_dlc,
            sync_mode_i  => sync_mode,
            slot_valid_i => s_valid,
            slot_dlc_i   => s_dlc_vec,
            period_us_i  => period_us_i,
            cfg_err_i    => cfg_err,
            bits_o       => f_bits,
            feasible_o   => feasible
        );

    -- ---------------------------------------------------------------------------------------------
    -- Read multiplexer (registered: the data of reg_addr_i is on reg_rdata_o one cycle later)
    -- ---------------------------------------------------------------------------------------------
    read_mux_proc : process (bc4x2, cfg_err, cyc_cnt, enable_i, f_bits, feasible, k_reg, m_reg,
                             master_id, n_axes, nmt_due, nt_rd_word, par_dlc, par_due, par_hi,
                             par_lo, par_node, par_type, pending, pmb_any, pmb_dlc, pmb_hi, pmb_lo,
                             pmb_new, pmb_ovr, pmb_sender, pmb_type, q_open, qwin_reg, reg_addr_i,
                             sender, staging, stop_due, stop_miss, sync_mode) is

        variable a : std_logic_vector(5 downto 0);
        variable v : std_logic_vector(31 downto 0);

    begin

        a := reg_addr_i;
        -- the node table's registers (OMNI_SEL, OMNI_SLOT_CFG, OMNI_SLOT_ERR, OMNI_FB_*,
        -- OMNI_FB_NEW, OMNI_ALIVE, OMNI_MISSING): its read data, 0 at the other offsets
        v := nt_rd_word;

        put(v, a, off_info_c,
            at(std_logic_vector(to_unsigned(N_SLOTS, 4)), OMNI_INFO_N_SLOTS_HI_C,
                  OMNI_INFO_N_SLOTS_LO_C));
        put(v, a, off_cfg_c,
            at(master_id, OMNI_CFG_MASTER_ID_HI_C, OMNI_CFG_MASTER_ID_LO_C)
            or at(n_axes, OMNI_CFG_N_AXES_HI_C, OMNI_CFG_N_AXES_LO_C)
            or at(bc4x2, OMNI_CFG_BCAST_4X2_C) or at(sender, OMNI_CFG_SENDER_C)
            or at(sync_mode, OMNI_CFG_SYNC_MODE_C) or at(stop_miss, OMNI_CFG_STOP_ON_MISSING_C));
        put(v, a, off_stat_c,
            at(pending, OMNI_STATUS_PENDING_C) or at(not feasible, OMNI_STATUS_INFEASIBLE_C)
            or at(cfg_err, OMNI_STATUS_CFG_ERR_C) or at(nmt_due, OMNI_STATUS_NMT_BUSY_C)
            or at(par_due, OMNI_STATUS_PARAM_BUSY_C) or at(q_open, OMNI_STATUS_QUERY_OPEN_C)
            or at(stop_due, OMNI_STATUS_STOP_DUE_C) or at(enable_i, OMNI_STATUS_ENABLED_C));
        put(v, a, off_k_c, at(std_logic_vector(k_reg), OMNI_SYNC_K_K_HI_C, OMNI_SYNC_K_K_LO_C));
        put(v, a, off_poll_c, at(std_logic_vector(m_reg), OMNI_POLL_M_HI_C, OMNI_POLL_M_LO_C));
        put(v, a, off_qwin_c,
            at(std_logic_vector(qwin_reg), OMNI_QUERY_WIN_US_HI_C, OMNI_QUERY_WIN_US_LO_C));
        put(v, a, off_cycle_c,
            at(std_logic_vector(cyc_cnt), OMNI_CYCLE_COUNT_HI_C, OMNI_CYCLE_COUNT_LO_C));

        for i in 0 to 3 loop

            put(v, a, off_sp_c + i,
                at(staging(2 * i), OMNI_SP01_AXIS0_HI_C, OMNI_SP01_AXIS0_LO_C)
                or at(staging(2 * i + 1), OMNI_SP01_AXIS1_HI_C, OMNI_SP01_AXIS1_LO_C));

        end loop;

        put(v, a, off_phdr_c,
            at(par_node, OMNI_PARAM_HDR_NODE_HI_C, OMNI_PARAM_HDR_NODE_LO_C)
            or at(par_type, OMNI_PARAM_HDR_TYPE_HI_C, OMNI_PARAM_HDR_TYPE_LO_C)
            or at(par_dlc, OMNI_PARAM_HDR_DLC_HI_C, OMNI_PARAM_HDR_DLC_LO_C));
        put(v, a, off_plo_c, par_lo);
        put(v, a, off_phi_c, at(par_hi, OMNI_PARAM_HI_DATA_HI_C, OMNI_PARAM_HI_DATA_LO_C));
        put(v, a, off_pmbi_c,
            at(pmb_ovr, OMNI_PMB_INFO_OVERRUN_C) or at(pmb_new, OMNI_PMB_INFO_NEW_C));

        if pmb_any = '1' then
            put(v, a, off_pmbi_c,
                at(pmb_sender, OMNI_PMB_INFO_SENDER_HI_C, OMNI_PMB_INFO_SENDER_LO_C)
                or at(pmb_type, OMNI_PMB_INFO_TYPE_HI_C, OMNI_PMB_INFO_TYPE_LO_C)
                or at(pmb_dlc, OMNI_PMB_INFO_DLC_HI_C, OMNI_PMB_INFO_DLC_LO_C));
            put(v, a, off_pmblo_c, pmb_lo);
            put(v, a, off_pmbhi_c, at(pmb_hi, OMNI_PMB_HI_DATA_HI_C, OMNI_PMB_HI_DATA_LO_C));
        end if;

        put(v, a, off_bits_c, at(f_bits, OMNI_BUS_BITS_BITS_HI_C, OMNI_BUS_BITS_BITS_LO_C));

        rd_mux <= v;

    end process read_mux_proc;

    rd_data_proc : process (clk_i) is
    begin

        if rising_edge(clk_i) then
            rdata_q <= rd_mux;
            -- OMNI_CNT_FB_RX .. OMNI_CNT_PARAM_RX: the counter bank's registered read
            if unsigned(reg_addr_i) >= off_cnt_c
               and unsigned(reg_addr_i) < off_cnt_c + cnt_num_c then
                cnt_sel_q <= '1';
            else
                cnt_sel_q <= '0';
            end if;
        end if;

    end process rd_data_proc;

    -- ---------------------------------------------------------------------------------------------
    -- Counters: nine 32-bit saturating counters in block RAM, one shared incrementer. Read lag:
    -- an event of cycle e is shown by every read with the address in cycle e + 13 or later
    -- (amounts registered here: + 1; the bank: S + 3 = 12 with S = 9); docs/omni_engine.md
    -- ---------------------------------------------------------------------------------------------
    cnt_ra <= std_logic_vector(resize(unsigned(reg_addr_i) - off_cnt_c, 4));

    cnt_bank_inst : entity work.canopen_counter_bank
        generic map (
            N_CNT    => cnt_num_c,
            CNT_BITS => 32,
            INC_BITS => inc_w_c
        )
        port map (
            clk_i     => clk_i,
            rst_n_i   => rst_n_i,
            inc_i     => cnt_inc,
            clr_i     => clr,
            rd_addr_i => cnt_ra,
            rd_data_o => cnt_q
        );

    -- simulation only: the received frame must not change from rx_valid_i until rx_done_o
    -- pragma translate_off
    rx_hold_check_proc : process (clk_i) is

        variable held : std_logic_vector(79 downto 0);

    begin

        if rising_edge(clk_i) then
            hold_check(held, rx_st /= S_RX_IDLE, rx_id_i & rx_rtr_i & rx_dlc_i & rx_data_i,
                       "omni_engine: rx_*_i (until rx_done_o)");
        end if;

    end process rx_hold_check_proc;

    -- pragma translate_on

    -- ---------------------------------------------------------------------------------------------
    -- Outputs
    -- ---------------------------------------------------------------------------------------------
    feasible_o      <= feasible;
    reg_rdata_o     <= cnt_q when cnt_sel_q = '1' else
                       rdata_q;
    rx_done_o       <= rx_done_q;
    rx_reply_o      <= rx_reply_q;
    rx_unexpected_o <= rx_unexp_q;
    tx_req_o        <= tx_req;
    tx_id_o         <= tx_id;
    tx_rtr_o        <= tx_rtr;
    tx_dlc_o        <= tx_dlc;
    tx_data_o       <= tx_data;
    ev_o            <= ev_q;

end architecture rtl;
