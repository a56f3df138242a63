-- =================================================================================================
-- Title    : omni_node_table
-- Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
-- SPDX-License-Identifier: Apache-2.0
-- =================================================================================================
-- Module:
--   The node table of the Omni-ID engine (part of omni_engine, which decodes the host window,
--   runs the receiver and the query window and instantiates this block).
-- Purpose:
--   * N_SLOTS slots: node-ID, function code, DLC and VALID of the feedback frame a slot expects
--     (OMNI_SLOT_CFG of the selected slot).
--   * Slot search on the frame being handed over (registered with it): the feedback slot
--     (function code and byte 0 = the slot's node) and the query-reply slot (node-ID in the id).
--   * Feedback RAM: the stored frame's data, sequence number and cycle count per slot, read at
--     the host's selection (OMNI_SEL) into a snapshot (OMNI_FB_LO / HI / INFO).
--   * Slot counters SEQ, LEN_ERR and MISSED of every slot in block RAM (one 48-bit word per
--     slot, plus a 32-bit host copy for OMNI_SLOT_ERR), written by the match cycle or by a
--     MISSED sweep; per-slot stale flags stand in for reset and CLR_COUNTERS.
--   * Flags: NEW (feedback not acknowledged), GOT (feedback in the current cycle: missed
--     cycles), ALIVE (replied to the last query), MISSING (sticky after a query window).
--   * Read data of its registers (OMNI_SEL, OMNI_SLOT_CFG, OMNI_SLOT_ERR, OMNI_FB_*,
--     OMNI_ALIVE, OMNI_MISSING) for the engine's registered read multiplexer.
--   Timing and decisions: docs/omni_engine.md (Node table, Slot counters in block RAM).
-- =================================================================================================

library ieee;
    use ieee.std_logic_1164.all;
    use ieee.numeric_std.all;

library work;
    use work.canopen_regs_pkg.all;
    use work.canopen_util_pkg.all;

entity omni_node_table is
    generic (
        N_SLOTS : positive range 1 to 8 := 8 -- node-table slots
    );
    port (
        -- clock and reset
        clk_i   : in    std_logic; -- system clock
        rst_n_i : in    std_logic; -- async reset, active low (synced)
        -- host window (decoded by omni_engine): strobes of the node-table registers, the
        -- write data, CLR_COUNTERS, the read address and this block's part of the read data
        wr_sel_i   : in    std_logic;                     -- OMNI_SEL written
        wr_scfg_i  : in    std_logic;                     -- OMNI_SLOT_CFG written
        wr_fbnew_i : in    std_logic;                     -- OMNI_FB_NEW written (W1C)
        wr_miss_i  : in    std_logic;                     -- OMNI_MISSING written (W1C)
        wdata_i    : in    std_logic_vector(31 downto 0); -- write data
        clr_i      : in    std_logic;                     -- OMNI_CTRL.CLR_COUNTERS
        reg_addr_i : in    std_logic_vector(5 downto 0);  -- word offset in the window
        rd_word_o  : out   std_logic_vector(31 downto 0); -- its register at reg_addr_i, or 0
        -- cycle
        cycle_close_i : in    std_logic;                     -- cycle_i while running (GOT)
        cycle_check_i : in    std_logic;                     -- with it: count missed cycles
        cyc_cnt_i     : in    std_logic_vector(15 downto 0); -- cycle count (feedback stamp)
        miss_cnt_o    : out   std_logic_vector(3 downto 0);  -- slots missed at cycle_check_i
        -- frame hand-over and match (the caller holds rx_*_i until its match cycle is over)
        hand_i      : in    std_logic;                     -- strobe: frame handed over
        rx_id_i     : in    std_logic_vector(10 downto 0); -- identifier
        rx_dlc_i    : in    std_logic_vector(3 downto 0);  -- data length code
        rx_data_i   : in    std_logic_vector(63 downto 0); -- byte k at 8k+7..8k
        fb_hit_o    : out   std_logic;                     -- a slot expects this feedback
        fb_dlc_ok_o : out   std_logic;                     -- with its DLC
        rep_hit_o   : out   std_logic;                     -- a slot's node sent this reply
        store_i     : in    std_logic;                     -- match cycle: store feedback
        len_err_i   : in    std_logic;                     -- match cycle: length error
        reply_i     : in    std_logic;                     -- match cycle: query reply
        -- query window (omni_engine)
        q_start_i   : in    std_logic;                    -- strobe: query sent, ALIVE cleared
        q_open_i    : in    std_logic;                    -- window open: replies count
        q_eval_i    : in    std_logic;                    -- strobe: window closed
        qmiss_any_o : out   std_logic;                    -- a valid slot did not reply
        qmiss_cnt_o : out   std_logic_vector(3 downto 0); -- how many
        -- slot configuration for the feasibility check
        slot_valid_o : out   std_logic_vector(N_SLOTS - 1 downto 0);    -- VALID of slot k
        slot_dlc_o   : out   std_logic_vector(4 * N_SLOTS - 1 downto 0) -- its DLC, 4k+3..4k
    );
end entity omni_node_table;

architecture rtl of omni_node_table is

    constant fram_w_c : positive := 64 + 16 + 16; -- data, seq, cycle

    -- no slot flagged
    constant zero_slots_c : std_logic_vector(N_SLOTS - 1 downto 0) := (others => '0');

    -- register window offsets (address - REG_OMNI_WIN_C)
    constant off_sel_c    : natural := REG_OMNI_SEL_C - REG_OMNI_WIN_C;
    constant off_scfg_c   : natural := REG_OMNI_SLOT_CFG_C - REG_OMNI_WIN_C;
    constant off_fblo_c   : natural := REG_OMNI_FB_LO_C - REG_OMNI_WIN_C;
    constant off_fbhi_c   : natural := REG_OMNI_FB_HI_C - REG_OMNI_WIN_C;
    constant off_fbinfo_c : natural := REG_OMNI_FB_INFO_C - REG_OMNI_WIN_C;
    constant off_serr_c   : natural := REG_OMNI_SLOT_ERR_C - REG_OMNI_WIN_C;
    constant off_fbnew_c  : natural := REG_OMNI_FB_NEW_C - REG_OMNI_WIN_C;
    constant off_alive_c  : natural := REG_OMNI_ALIVE_C - REG_OMNI_WIN_C;
    constant off_miss_c   : natural := REG_OMNI_MISSING_C - REG_OMNI_WIN_C;

    type u8_arr_t is array (natural range <>) of std_logic_vector(7 downto 0);

    type fc_arr_t is array (natural range <>) of std_logic_vector(2 downto 0);

    type nib_arr_t is array (natural range <>) of std_logic_vector(3 downto 0);

    -- MISSED increments not yet added to the RAM word, per slot

    type u2_arr_t is array (natural range <>) of unsigned(1 downto 0);

    type fram_t is array (0 to N_SLOTS - 1) of std_logic_vector(fram_w_c - 1 downto 0);

    -- number of '1' bits, as a 4-bit amount

    function ones (v : std_logic_vector) return std_logic_vector is

        variable c : natural range 0 to 8;

    begin

        c := 0;

        for i in v'range loop

            if v(i) = '1' then
                c := c + 1;
            end if;

        end loop;

        return std_logic_vector(to_unsigned(c, 4));

    end function ones;

    -- slot configuration
    signal s_node  : u8_arr_t(0 to N_SLOTS - 1);
    signal s_fc    : fc_arr_t(0 to N_SLOTS - 1);
    signal s_dlc   : nib_arr_t(0 to N_SLOTS - 1);
    signal s_valid : std_logic_vector(N_SLOTS - 1 downto 0);
    -- feedback not acknowledged; stored since reset; stored since the last cycle_close_i
    signal s_new : std_logic_vector(N_SLOTS - 1 downto 0);
    signal s_ok  : std_logic_vector(N_SLOTS - 1 downto 0);
    signal s_got : std_logic_vector(N_SLOTS - 1 downto 0);
    -- replies of the last query, sticky missing; valid slots that did not reply
    signal alive   : std_logic_vector(N_SLOTS - 1 downto 0);
    signal missing : std_logic_vector(N_SLOTS - 1 downto 0);
    signal qmiss   : std_logic_vector(N_SLOTS - 1 downto 0);
    -- slots missed in the cycle closing now (cycle_check_i)
    signal miss_now : std_logic_vector(N_SLOTS - 1 downto 0);

    -- slot search on the frame at rx_*_i, and its result registered at the hand-over
    signal mi_fb_any  : std_logic;
    signal mi_fb_idx  : natural range 0 to N_SLOTS - 1;
    signal mi_rep_any : std_logic;
    signal mi_rep_idx : natural range 0 to N_SLOTS - 1;
    signal m_fb_any   : std_logic;
    signal m_fb_idx   : natural range 0 to N_SLOTS - 1;
    signal m_rep_any  : std_logic;
    signal m_rep_idx  : natural range 0 to N_SLOTS - 1;

    -- slot counters SEQ, LEN_ERR, MISSED in block RAM, one word per slot: a field reads 0
    -- until written after a reset (SEQ: s_ok) or a CLR_COUNTERS (LEN_ERR, MISSED: *_stale)
    signal len_stale  : std_logic_vector(N_SLOTS - 1 downto 0);
    signal miss_stale : std_logic_vector(N_SLOTS - 1 downto 0);
    -- engine copy: written by the match cycle (SEQ / LEN_ERR) or the MISSED sweep, read at a
    -- frame's hand-over or by the sweep
    signal sc_mwe : std_logic;
    signal sc_we  : std_logic;
    signal sc_wa  : natural range 0 to N_SLOTS - 1;
    signal sc_wd  : std_logic_vector(47 downto 0);
    signal sc_ra  : natural range 0 to N_SLOTS - 1;
    signal sc_q   : std_logic_vector(47 downto 0);
    -- host copy (LEN_ERR and MISSED) read at the selection
    signal hc_q  : std_logic_vector(31 downto 0);
    signal hl_ok : std_logic;
    signal hm_ok : std_logic;
    -- MISSED: cycles missed by a slot and not yet added (0..3); the sweep that adds them (slot,
    -- phase 0 read / 1 write; it waits while the match uses the port) and its write
    signal miss_ev   : std_logic_vector(N_SLOTS - 1 downto 0);
    signal miss_pend : u2_arr_t(0 to N_SLOTS - 1);
    signal sw_slot   : natural range 0 to N_SLOTS - 1;
    signal sw_ph     : std_logic;
    signal sw_free   : std_logic;
    signal sw_we     : std_logic;
    signal sw_miss   : std_logic_vector(15 downto 0);
    -- the visited slot's stale flag and pending count, registered with its read (phase 0);
    -- the write adds that count and takes it off the pending one
    signal sw_stale : std_logic;
    signal sw_pend  : unsigned(1 downto 0);
    -- SEQ and LEN_ERR of the matched slot: read from the RAM at the hand-over edge, with the
    -- word's validity registered at that edge (a counter clear at that edge included); + 1
    signal m_seq_ok    : std_logic;
    signal m_len_ok    : std_logic;
    signal m_seq       : unsigned(15 downto 0);
    signal m_len       : unsigned(15 downto 0);
    signal rx_seq_next : unsigned(15 downto 0);
    signal rx_len_next : unsigned(15 downto 0);

    -- feedback RAM (synchronous read at the host's select)
    signal fram  : fram_t;
    signal fr_wd : std_logic_vector(fram_w_c - 1 downto 0);
    signal fr_re : std_logic;
    signal fr_ra : natural range 0 to N_SLOTS - 1;
    signal fr_q  : std_logic_vector(fram_w_c - 1 downto 0);
    -- host selection (OMNI_SEL.SLOT written now), as of the next edge, its RAM address
    signal w_sel     : natural range 0 to 7;
    signal hsel_next : natural range 0 to 7;
    signal hsel_ra   : natural range 0 to N_SLOTS - 1;
    -- host selection, snapshot NEW, snapshot holds a stored frame
    signal sel_slot : natural range 0 to 7;
    signal snap_new : std_logic;
    signal snap_ok  : std_logic;

begin

    w_sel <= to_integer(unsigned(wdata_i(OMNI_SEL_SLOT_HI_C downto OMNI_SEL_SLOT_LO_C)));

    -- ---------------------------------------------------------------------------------------------
    -- Slot search on the frame being handed over (registered with it: the compares of the
    -- table are not in the path of the engine's classification and the SEQ / LEN_ERR update)
    -- ---------------------------------------------------------------------------------------------
    slot_match_proc : process (rx_data_i, rx_id_i, s_fc, s_node, s_valid) is
    begin

        mi_fb_any  <= '0';
        mi_fb_idx  <= 0;
        mi_rep_any <= '0';
        mi_rep_idx <= 0;

        for k in N_SLOTS - 1 downto 0 loop

            if s_valid(k) = '1' and s_node(k) = rx_data_i(7 downto 0)
               and s_fc(k) = rx_id_i(10 downto 8) then
                mi_fb_any <= '1';
                mi_fb_idx <= k;
            end if;

            if s_valid(k) = '1' and s_node(k) = rx_id_i(7 downto 0) then
                mi_rep_any <= '1';
                mi_rep_idx <= k;
            end if;

        end loop;

    end process slot_match_proc;

    -- the matched slot's DLC against the frame's (match cycle)
    dlc_ok_proc : process (m_fb_idx, rx_dlc_i, s_dlc) is
    begin

        fb_dlc_ok_o <= '0';

        for k in 0 to N_SLOTS - 1 loop

            if m_fb_idx = k and s_dlc(k) = rx_dlc_i then
                fb_dlc_ok_o <= '1';
            end if;

        end loop;

    end process dlc_ok_proc;

    fb_hit_o  <= m_fb_any;
    rep_hit_o <= m_rep_any;

    rx_seq_next <= m_seq + 1;
    rx_len_next <= sat_inc(m_len);

    -- missed slots: at a cycle close, valid and without feedback; after a query window, valid
    -- and without reply
    miss_now <= s_valid and not s_got when cycle_check_i = '1' else
                zero_slots_c;
    qmiss    <= s_valid and not alive;

    miss_cnt_o  <= ones(miss_now);
    qmiss_cnt_o <= ones(qmiss);
    qmiss_any_o <= '0' when qmiss = zero_slots_c else
                   '1';

    -- ---------------------------------------------------------------------------------------------
    -- Slot configuration, flags, host selection
    -- ---------------------------------------------------------------------------------------------
    table_proc : process (clk_i, rst_n_i) is

        variable new_v : std_logic;

    begin

        if rst_n_i = '0' then
            s_node    <= (others => (others => '0'));
            s_fc      <= (others => (others => '0'));
            s_dlc     <= (others => (others => '0'));
            s_valid   <= (others => '0');
            s_new     <= (others => '0');
            s_ok      <= (others => '0');
            s_got     <= (others => '0');
            miss_ev   <= (others => '0');
            alive     <= (others => '0');
            missing   <= (others => '0');
            sel_slot  <= 0;
            snap_new  <= '0';
            snap_ok   <= '0';
            m_fb_any  <= '0';
            m_fb_idx  <= 0;
            m_rep_any <= '0';
            m_rep_idx <= 0;
        elsif rising_edge(clk_i) then
            if hand_i = '1' then
                m_fb_any  <= mi_fb_any;
                m_fb_idx  <= mi_fb_idx;
                m_rep_any <= mi_rep_any;
                m_rep_idx <= mi_rep_idx;
            end if;

            -- per-slot MISSED: to the slot counter sweep (a clear drops its own cycle's events)
            miss_ev <= miss_now;
            if clr_i = '1' then
                miss_ev <= (others => '0');
            end if;

            if wr_sel_i = '1' then
                sel_slot <= w_sel;
                snap_new <= '0';
                snap_ok  <= '0';

                for k in 0 to N_SLOTS - 1 loop

                    if w_sel = k then
                        snap_new <= s_new(k);
                        snap_ok  <= s_ok(k);
                    end if;

                end loop;

            end if;

            if q_start_i = '1' then
                alive <= (others => '0');
            end if;

            for k in 0 to N_SLOTS - 1 loop

                new_v := s_new(k);

                if wr_scfg_i = '1' and sel_slot = k then
                    s_node(k)  <= wdata_i(OMNI_SLOT_CFG_NODE_HI_C downto OMNI_SLOT_CFG_NODE_LO_C);
                    s_fc(k)    <= wdata_i(OMNI_SLOT_CFG_FC_HI_C downto OMNI_SLOT_CFG_FC_LO_C);
                    s_valid(k) <= wdata_i(OMNI_SLOT_CFG_VALID_C);
                    s_dlc(k)   <= wdata_i(OMNI_SLOT_CFG_DLC_HI_C downto OMNI_SLOT_CFG_DLC_LO_C);
                    -- the current cycle is not checked after a configuration write
                    s_got(k) <= '1';
                elsif cycle_close_i = '1' then
                    -- the cycle closes first: a feedback in the same cycle counts for the next
                    s_got(k) <= '0';
                    if store_i = '1' and m_fb_idx = k then
                        s_got(k) <= '1';
                    end if;
                elsif store_i = '1' and m_fb_idx = k then
                    s_got(k) <= '1';
                end if;

                -- NEW: OMNI_SEL.ACK with the selection or OMNI_FB_NEW written 1, then reception
                if (wr_sel_i = '1' and wdata_i(OMNI_SEL_ACK_C) = '1' and w_sel = k)
                   or (wr_fbnew_i = '1' and wdata_i(k) = '1') then
                    new_v := '0';
                end if;

                if store_i = '1' and m_fb_idx = k then
                    s_ok(k) <= '1';
                    new_v   := '1';
                end if;

                s_new(k) <= new_v;

                if reply_i = '1' and m_rep_idx = k and q_open_i = '1' then
                    alive(k) <= '1';
                end if;

                if wr_miss_i = '1' and wdata_i(k) = '1' then
                    missing(k) <= '0';
                end if;
                if q_eval_i = '1' and s_valid(k) = '1' and alive(k) = '0' then
                    missing(k) <= '1';
                end if;

            end loop;

        end if;

    end process table_proc;

    slot_gen : for k in 0 to N_SLOTS - 1 generate
        slot_dlc_o(4 * k + 3 downto 4 * k) <= s_dlc(k);
    end generate slot_gen;

    slot_valid_o <= s_valid;

    -- ---------------------------------------------------------------------------------------------
    -- Feedback RAM: written at a store, read at the host's select (snapshot)
    -- ---------------------------------------------------------------------------------------------
    fr_wd <= cyc_cnt_i & std_logic_vector(rx_seq_next) & keep_bytes(rx_data_i, rx_dlc_i);
    fr_re <= '1' when wr_sel_i = '1' and w_sel < N_SLOTS else
             '0';
    fr_ra <= w_sel when fr_re = '1' else
             0;

    fram_proc : process (clk_i) is
    begin

        if rising_edge(clk_i) then
            if store_i = '1' then
                fram(m_fb_idx) <= fr_wd;
            end if;
            if fr_re = '1' then
                fr_q <= fram(fr_ra);
            end if;
        end if;

    end process fram_proc;

    -- ---------------------------------------------------------------------------------------------
    -- Slot counters: SEQ, LEN_ERR and MISSED of every slot in block RAM (docs/omni_engine.md)
    -- ---------------------------------------------------------------------------------------------
    -- word layout: SEQ 15..0, LEN_ERR 31..16, MISSED 47..32. The match cycle writes the
    -- matched slot's word (a stored frame SEQ + 1, a length error LEN_ERR + 1 saturating;
    -- MISSED as read at the hand-over), the sweep a slot's MISSED + its pending count (SEQ and
    -- LEN_ERR as read by the sweep); the sweep keeps off the port in the hand-over and match
    -- cycles, so neither write loses the other's fields
    sc_mwe  <= store_i or len_err_i;
    sw_free <= not (hand_i or sc_mwe);
    sw_we   <= '1' when sw_ph = '1' and sw_free = '1' and sw_pend /= 0 else
               '0';
    sw_miss <= std_logic_vector(sat_add(unsigned(sc_q(47 downto 32))
                                        and (15 downto 0 => not sw_stale),
                                        to_integer(sw_pend)));

    sc_we <= sc_mwe or sw_we;
    sc_wa <= m_fb_idx when sc_mwe = '1' else
             sw_slot;
    sc_wd <= sc_q(47 downto 32) & std_logic_vector(m_len) & std_logic_vector(rx_seq_next)
             when store_i = '1' else
             sc_q(47 downto 32) & std_logic_vector(rx_len_next) & std_logic_vector(m_seq)
             when len_err_i = '1' else
             sw_miss & sc_q(31 downto 0);
    sc_ra <= mi_fb_idx when hand_i = '1' else
             sw_slot;

    -- the match cycle works on the word read at the hand-over edge
    m_seq <= unsigned(sc_q(15 downto 0)) when m_seq_ok = '1' else
             (others => '0');
    m_len <= unsigned(sc_q(31 downto 16)) when m_len_ok = '1' else
             (others => '0');

    sc_ram_inst : entity work.canopen_sdp_ram
        generic map (
            DEPTH => N_SLOTS,
            WIDTH => 48
        )
        port map (
            clk_i   => clk_i,
            we_i    => sc_we,
            waddr_i => sc_wa,
            wdata_i => sc_wd,
            re_i    => '1',
            raddr_i => sc_ra,
            rdata_o => sc_q
        );

    -- the host's selection as of the next edge (a slot number >= N_SLOTS reads 0)
    hsel_next <= w_sel when wr_sel_i = '1' else
                 sel_slot;
    hsel_ra   <= hsel_next when hsel_next < N_SLOTS else
                 0;

    hc_ram_inst : entity work.canopen_sdp_ram
        generic map (
            DEPTH => N_SLOTS,
            WIDTH => 32
        )
        port map (
            clk_i   => clk_i,
            we_i    => sc_we,
            waddr_i => sc_wa,
            wdata_i => sc_wd(47 downto 16),
            re_i    => '1',
            raddr_i => hsel_ra,
            rdata_o => hc_q
        );

    slot_cnt_proc : process (clk_i, rst_n_i) is

        variable p_v : unsigned(1 downto 0);

    begin

        if rst_n_i = '0' then
            len_stale  <= (others => '1');
            miss_stale <= (others => '1');
            miss_pend  <= (others => (others => '0'));
            sw_slot    <= 0;
            sw_ph      <= '0';
            sw_stale   <= '1';
            sw_pend    <= (others => '0');
            m_seq_ok   <= '0';
            m_len_ok   <= '0';
            hl_ok      <= '0';
            hm_ok      <= '0';
        elsif rising_edge(clk_i) then
            -- validity of the words read at this edge (as before this edge's writes)
            if hand_i = '1' then
                m_seq_ok <= s_ok(mi_fb_idx);
                m_len_ok <= not (len_stale(mi_fb_idx) or clr_i);
            end if;
            hl_ok <= '0';
            hm_ok <= '0';
            if hsel_next < N_SLOTS then
                hl_ok <= not len_stale(hsel_ra);
                hm_ok <= not miss_stale(hsel_ra);
            end if;

            -- sweep: phase 0 reads sw_slot, phase 1 writes it and moves on; a cycle in which
            -- the match uses the port, or a clear, sends it back to phase 0 (read again)
            if sw_ph = '0' then
                sw_stale <= miss_stale(sw_slot);
                sw_pend  <= miss_pend(sw_slot);
            end if;
            sw_ph <= '0';
            if sw_free = '1' and clr_i = '0' then
                sw_ph <= not sw_ph;
                if sw_ph = '1' then
                    if sw_slot = N_SLOTS - 1 then
                        sw_slot <= 0;
                    else
                        sw_slot <= sw_slot + 1;
                    end if;
                end if;
            end if;

            for k in 0 to N_SLOTS - 1 loop

                if sc_mwe = '1' and m_fb_idx = k then
                    len_stale(k) <= '0';
                end if;

                p_v := miss_pend(k);
                if sw_we = '1' and sw_slot = k then
                    miss_stale(k) <= '0';
                    p_v           := p_v - sw_pend;
                end if;
                if miss_ev(k) = '1' and p_v /= 3 then
                    p_v := p_v + 1;
                end if;
                miss_pend(k) <= p_v;

                if clr_i = '1' then
                    len_stale(k)  <= '1';
                    miss_stale(k) <= '1';
                    miss_pend(k)  <= (others => '0');
                end if;

            end loop;

        end if;

    end process slot_cnt_proc;

    -- ---------------------------------------------------------------------------------------------
    -- Read data of the node-table registers (AND-OR form; the engine registers it)
    -- ---------------------------------------------------------------------------------------------
    read_proc : process (alive, fr_q, hc_q, hl_ok, hm_ok, missing, reg_addr_i, s_dlc, s_fc,
                         s_new, s_node, s_valid, sel_slot, snap_new, snap_ok) is

        variable v : std_logic_vector(31 downto 0);
        -- node-ID of the lowest missing slot (0: none)
        variable miss_node : std_logic_vector(7 downto 0);

    begin

        v := (others => '0');

        put(v, reg_addr_i, off_sel_c,
            at(std_logic_vector(to_unsigned(sel_slot, 3)), OMNI_SEL_SLOT_HI_C, OMNI_SEL_SLOT_LO_C)
            or at(snap_new, OMNI_SEL_NEW_C));

        for k in 0 to N_SLOTS - 1 loop

            if sel_slot = k then
                put(v, reg_addr_i, off_scfg_c,
                    at(s_node(k), OMNI_SLOT_CFG_NODE_HI_C, OMNI_SLOT_CFG_NODE_LO_C)
                    or at(s_fc(k), OMNI_SLOT_CFG_FC_HI_C, OMNI_SLOT_CFG_FC_LO_C)
                    or at(s_valid(k), OMNI_SLOT_CFG_VALID_C)
                    or at(s_dlc(k), OMNI_SLOT_CFG_DLC_HI_C, OMNI_SLOT_CFG_DLC_LO_C));
            end if;

        end loop;

        -- the slot counters' host copies (read at the selection, 0 for no slot or a stale word)
        put(v, reg_addr_i, off_serr_c,
            at(hc_q(15 downto 0) and (15 downto 0 => hl_ok), OMNI_SLOT_ERR_LEN_ERR_HI_C,
               OMNI_SLOT_ERR_LEN_ERR_LO_C)
            or at(hc_q(31 downto 16) and (15 downto 0 => hm_ok), OMNI_SLOT_ERR_MISSED_HI_C,
                  OMNI_SLOT_ERR_MISSED_LO_C));

        -- the snapshot of the selected slot (sel_slot < N_SLOTS when snap_ok = 1)
        if snap_ok = '1' then
            put(v, reg_addr_i, off_fblo_c, fr_q(31 downto 0));
            put(v, reg_addr_i, off_fbhi_c, fr_q(63 downto 32));
            put(v, reg_addr_i, off_fbinfo_c,
                at(fr_q(79 downto 64), OMNI_FB_INFO_SEQ_HI_C, OMNI_FB_INFO_SEQ_LO_C)
                or at(fr_q(95 downto 80), OMNI_FB_INFO_CYCLE_HI_C, OMNI_FB_INFO_CYCLE_LO_C));
        end if;

        put(v, reg_addr_i, off_fbnew_c, at(s_new, N_SLOTS - 1, 0));
        put(v, reg_addr_i, off_alive_c, at(alive, N_SLOTS - 1, 0));
        miss_node := (others => '0');

        for k in N_SLOTS - 1 downto 0 loop

            if missing(k) = '1' then
                miss_node := s_node(k);
            end if;

        end loop;

        put(v, reg_addr_i, off_miss_c,
            at(missing, N_SLOTS - 1, 0)
            or at(miss_node, OMNI_MISSING_NODE_HI_C, OMNI_MISSING_NODE_LO_C));

        rd_word_o <= v;

    end process read_proc;

end architecture rtl;
