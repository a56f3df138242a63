-- =================================================================================================
-- Title    : canopen_node_monitor
-- Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
-- SPDX-License-Identifier: Apache-2.0
-- =================================================================================================
-- Module:
--   CANopen error control (heartbeat consumer, node guarding master), boot-up handling, per-node
--   NMT state and the EMCY consumer FIFO (CiA 301 7.2.8.3.2 error control, 7.2.7 EMCY).
-- Purpose:
--   Sits beside the master's FSM. In St7 "NMT processing" the FSM hands it every received frame
--   of function code 1110b (700h + node: heartbeat, boot-up, guarding reply) and every EMCY
--   (081h..0FFh) with rx_valid_i and waits for rx_done_o (2 clock cycles later, 3 or 4 when
--   an NMT start is requested: rx_reply_o, and tx_req_o is already up); rx_valid_i is ignored
--   while a frame is in process; the frame inputs are held from rx_valid_i until rx_done_o
--   and read where they are. The frames this block wants to send (guarding RTRs, NMT start
--   after a boot-up, NMT reset-node after a loss) wait behind tx_req_o and are taken with
--   tx_ack_i in St10 "new NMT".
--   * MAX_NODES slots, each configured by the host with a node-ID (0 = unused), a mode (off,
--     heartbeat consumer, node guarding), a time [ms], a life time factor and two options
--     (NMT start after boot-up, NMT reset-node after a loss).
--   * Heartbeat: a heartbeat loads the slot's loss timer with the consumer time T; the slot is
--     lost at the (T+1)-th ms tick after the last heartbeat, i.e. between T and T+1 ms later.
--     Monitoring starts with the first heartbeat and restarts with the first one after a
--     boot-up. T = 0 switches supervision off.
--   * Node guarding: an RTR on 700h + node every guard time G from the first tick after the
--     slot is enabled; every reply loads the loss timer with G x life time factor (the first
--     request does so too), a reply whose toggle bit repeats the previous one is a toggle error
--     (the expectation restarts at 0 with the first request and with each boot-up).
--   * A loss sets the sticky lost bit once and raises ev_lost; the next message from the node
--     makes it alive again and re-arms the supervision.
--   * EMCY frames from any node go into a FIFO (node, 8 bytes, time stamp) read by the host
--     (first-word fall-through, block RAM).
--   * Transmit requests are one pending bit per slot and kind, served round robin over the
--     slots (within a slot: reset-node, then start, then RTR); a repeated request of the same
--     kind merges with the pending one.
-- =================================================================================================

library ieee;
    use ieee.std_logic_1164.all;
    use ieee.numeric_std.all;

library work;
    use work.canopen_pkg.all;
    use work.canopen_util_pkg.all;

entity canopen_node_monitor is
    generic (
        MAX_NODES  : positive range 1 to 32 := 8; -- monitored slots
        EMCY_DEPTH : positive range 2 to 64 := 8  -- EMCY FIFO entries
    );
    port (
        -- clock and reset
        clk_i   : in    std_logic; -- system clock
        rst_n_i : in    std_logic; -- async reset, active low
        -- time base
        tick_ms_i : in    std_logic;                     -- 1-cycle strobe every ms
        time_ms_i : in    std_logic_vector(31 downto 0); -- free-running ms counter
        -- per-slot configuration, slot k in bits k*w+w-1 .. k*w
        cfg_node_i          : in    std_logic_vector(7 * MAX_NODES - 1 downto 0); -- node-ID
        cfg_mode_i          : in    std_logic_vector(2 * MAX_NODES - 1 downto 0); -- 01 hb, 10 ng
        cfg_autostart_i     : in    std_logic_vector(MAX_NODES - 1 downto 0);     -- start on boot
        cfg_reset_on_loss_i : in    std_logic_vector(MAX_NODES - 1 downto 0);     -- reset on loss
        -- per-slot time and life time factor: written into this block's RAM one slot at a
        -- time; a slot not written since reset (cfg_tl_ok_i = 0) has time 0 and factor 0
        cfg_tl_we_i   : in    std_logic;                                -- strobe: write slot
        cfg_tl_slot_i : in    std_logic_vector(4 downto 0);             -- slot (>= MAX_NODES: none)
        cfg_tl_time_i : in    std_logic_vector(15 downto 0);            -- T or G [ms]
        cfg_tl_life_i : in    std_logic_vector(7 downto 0);             -- life time factor
        cfg_tl_ok_i   : in    std_logic_vector(MAX_NODES - 1 downto 0); -- slot written
        -- per-slot status
        st_alive_o  : out   std_logic_vector(MAX_NODES - 1 downto 0); -- heard, not expired
        st_lost_o   : out   std_logic_vector(MAX_NODES - 1 downto 0); -- sticky: loss
        st_toggle_o : out   std_logic_vector(MAX_NODES - 1 downto 0); -- sticky: toggle error
        st_bootup_o : out   std_logic_vector(MAX_NODES - 1 downto 0); -- sticky: boot-up seen
        st_clear_i  : in    std_logic_vector(MAX_NODES - 1 downto 0); -- clear sticky bits
        -- status RAM read port (last NMT state or time of a slot, registered: +1 cycle)
        st_rd_slot_i : in    std_logic_vector(4 downto 0);  -- slot to read
        st_rd_nmt_i  : in    std_logic;                     -- 1: its NMT state, 0: its time
        st_rd_data_o : out   std_logic_vector(31 downto 0); -- state in 6..0, or time [ms]
        -- event strobes
        ev_lost_o   : out   std_logic_vector(MAX_NODES - 1 downto 0); -- strobe: loss
        ev_toggle_o : out   std_logic_vector(MAX_NODES - 1 downto 0); -- strobe: toggle error
        ev_bootup_o : out   std_logic_vector(MAX_NODES - 1 downto 0); -- strobe: boot-up
        ev_emcy_o   : out   std_logic;                                -- strobe: EMCY queued
        -- EMCY FIFO head (first-word fall-through)
        emcy_count_o : out   std_logic_vector(6 downto 0);  -- entries available
        emcy_lost_o  : out   std_logic;                     -- sticky: EMCY dropped, FIFO full
        emcy_clear_i : in    std_logic;                     -- clear emcy_lost_o
        emcy_node_o  : out   std_logic_vector(6 downto 0);  -- head: producer node-ID
        emcy_data_o  : out   std_logic_vector(63 downto 0); -- head: the 8 EMCY bytes
        emcy_time_o  : out   std_logic_vector(31 downto 0); -- head: time_ms_i at reception
        emcy_pop_i   : in    std_logic;                     -- pop the head
        -- frame to transmit
        tx_req_o  : out   std_logic;                     -- level: a frame is waiting
        tx_id_o   : out   std_logic_vector(10 downto 0); -- identifier
        tx_rtr_o  : out   std_logic;                     -- remote frame
        tx_dlc_o  : out   std_logic_vector(3 downto 0);  -- data length code
        tx_data_o : out   std_logic_vector(63 downto 0); -- byte k at 8k+7..8k
        tx_ack_i  : in    std_logic;                     -- strobe: frame taken
        -- received frame
        rx_valid_i      : in    std_logic;                     -- strobe: process this frame
        rx_id_i         : in    std_logic_vector(10 downto 0); -- identifier
        rx_rtr_i        : in    std_logic;                     -- remote frame
        rx_dlc_i        : in    std_logic_vector(3 downto 0);  -- data length code
        rx_data_i       : in    std_logic_vector(63 downto 0); -- byte k at 8k+7..8k
        rx_done_o       : out   std_logic;                     -- strobe: frame processed
        rx_reply_o      : out   std_logic;                     -- with done: NMT frame requested
        rx_unexpected_o : out   std_logic;                     -- with done: not monitored, RTR
        rx_malformed_o  : out   std_logic                      -- with done: wrong DLC
    );
end entity canopen_node_monitor;

architecture rtl of canopen_node_monitor is

    -- ---------------------------------------------------------------------------------------------
    -- Constants: slot modes (this block's register encoding) and CiA 301 frame layouts that
    -- canopen_pkg does not name
    -- ---------------------------------------------------------------------------------------------
    constant mode_heartbeat_c : std_logic_vector(1 downto 0) := "01"; -- heartbeat consumer
    constant mode_guarding_c  : std_logic_vector(1 downto 0) := "10"; -- node guarding
    constant ec_dlc_c         : std_logic_vector(3 downto 0) := x"1"; -- error control: state
    constant emcy_dlc_c       : std_logic_vector(3 downto 0) := x"8"; -- EMCY: 8 bytes
    constant nmt_dlc_c        : std_logic_vector(3 downto 0) := x"2"; -- NMT: cs, node-ID
    constant toggle_bit_c     : natural                      := 7;    -- guarding reply toggle
    constant node_none_c      : node_id_t                    := (others => '0');
    -- EMCY FIFO entry: node-ID (7) & data (64) & time (32)
    constant emcy_w_c : natural := 7 + 64 + 32;
    -- slot word in the slot RAM: loss timer sub (16) and fac (8), guard period counter (16),
    -- armed, guarding running, expected toggle, node-ID and mode of the last visit (a change
    -- restarts the slot)
    constant w_sub_c   : natural := 0;  -- 15..0
    constant w_fac_c   : natural := 16; -- 23..16
    constant w_gcnt_c  : natural := 24; -- 39..24
    constant w_armed_c : natural := 40;
    constant w_run_c   : natural := 41;
    constant w_exp_c   : natural := 42;
    constant w_node_c  : natural := 43; -- 49..43
    constant w_mode_c  : natural := 50; -- 51..50
    constant slot_w_c  : natural := 52;
    -- time RAM word: time, life time factor, time /= 0, time <= 1, factor /= 0
    constant tl_time_c : natural := 0;  -- 15..0
    constant tl_life_c : natural := 16; -- 23..16
    constant tl_tnz_c  : natural := 24;
    constant tl_tle1_c : natural := 25;
    constant tl_lnz_c  : natural := 26;
    constant tl_w_c    : natural := 27;

    function check_config return boolean is
    begin

        assert MAX_NODES <= 32 and EMCY_DEPTH >= 2 and EMCY_DEPTH <= 64
            report "canopen_node_monitor: MAX_NODES must be 1..32, EMCY_DEPTH 2..64"
            severity failure;
        report "canopen_node_monitor: " & integer'image(MAX_NODES) & " slots (RAM "
               & integer'image(MAX_NODES) & " x " & integer'image(slot_w_c) & " bits), EMCY FIFO "
               & integer'image(EMCY_DEPTH) & " x " & integer'image(emcy_w_c) & " bits"
            severity note;
        return true;

    end function check_config;

    constant config_ok_c : boolean := check_config;

    -- ---------------------------------------------------------------------------------------------
    -- Types
    -- ---------------------------------------------------------------------------------------------

    subtype slot_t is natural range 0 to MAX_NODES - 1;

    -- receive sequencer

    type rx_state_t is (
        S_RX_IDLE,  -- wait for rx_valid_i
        S_RX_MATCH, -- classify the frame, find the slot of its node, read its slot word
        S_RX_APPLY, -- update the slot / push the EMCY, report (unless a reply waits)
        S_RX_REPLY  -- autostart requested: report once tx_req_o shows it
    );

    -- what the received frame is

    type rx_class_t is (RX_EC, RX_EMCY, RX_UNEXPECTED, RX_MALFORMED);

    -- kind of a transmit request

    type tx_kind_t is (TX_RESET, TX_START, TX_RTR);

    -- ---------------------------------------------------------------------------------------------
    -- Signals
    -- ---------------------------------------------------------------------------------------------
    -- time_ms_i at the edge that samples rx_valid_i (datapath); the frame itself is read on
    -- rx_*_i, held by the caller from rx_valid_i until rx_done_o (no copy)
    signal rx_time_q : std_logic_vector(31 downto 0);
    -- receive sequencer state, class of the frame, one-hot slot of its node (first match)
    signal rx_state : rx_state_t;
    signal rx_class : rx_class_t;
    signal rx_hit   : std_logic_vector(MAX_NODES - 1 downto 0);
    -- slots whose node-ID is the frame's (registered with the latch)
    signal rx_eq_q : std_logic_vector(MAX_NODES - 1 downto 0);
    -- slot matcher (S_RX_MATCH): one-hot first slot with the frame's node, its index, any
    signal match_hit : std_logic_vector(MAX_NODES - 1 downto 0);
    signal match_idx : slot_t;
    signal match_any : std_logic;
    -- apply stage: error-control frame, its state byte and toggle bit, what it leads to
    signal rx_apply          : std_logic;
    signal rx_state_byte     : std_logic_vector(6 downto 0);
    signal rx_toggle         : std_logic;
    signal apply_reply       : std_logic;
    signal apply_unsolicited : std_logic;

    -- slot RAM: read address (this cycle), slot word read (next cycle), word written back
    signal ram_raddr : slot_t;
    signal ram_rdata : std_logic_vector(slot_w_c - 1 downto 0);
    signal one       : std_logic;
    -- slot engine: the slot read in the previous cycle (visited in this one), a sweep visit
    -- in this cycle, the next slot of the sweep, a visit (sweep or frame) in this cycle
    signal eng_slot : slot_t;
    signal sw_phase : std_logic;
    signal sw_slot  : slot_t;
    signal sw_1h    : std_logic_vector(MAX_NODES - 1 downto 0);
    -- the slot read in this cycle, one-hot
    signal rd_1h : std_logic_vector(MAX_NODES - 1 downto 0);
    signal visit : std_logic;
    -- configuration of the slot read in this cycle (ram_raddr), and registered: of eng_slot
    -- (shared datapath), with its heartbeat / guarding / supervision flags and its valid bit;
    -- time and life time factor come from the time RAM read at ram_raddr, with the flags
    -- computed when they were written (time /= 0, time <= 1, factor /= 0)
    signal m_node     : node_id_t;
    signal m_mode     : std_logic_vector(1 downto 0);
    signal m_ok       : std_logic;
    signal m_valid    : std_logic;
    signal v_node     : node_id_t;
    signal v_mode     : std_logic_vector(1 downto 0);
    signal v_time     : unsigned(15 downto 0);
    signal v_life     : unsigned(7 downto 0);
    signal v_hb_cfg   : boolean;
    signal v_ng_cfg   : boolean;
    signal v_hb       : boolean;
    signal v_guard    : boolean;
    signal v_sup      : boolean;
    signal v_time_le1 : boolean;
    signal v_valid    : std_logic;
    -- time RAM: write slot in range, word written (time, factor, the three flags), word read
    signal tl_we    : std_logic;
    signal tl_waddr : slot_t;
    signal tl_wdata : std_logic_vector(tl_w_c - 1 downto 0);
    signal tl_rdata : std_logic_vector(tl_w_c - 1 downto 0);
    -- result of the visit: slot word, node heard, boot-up, toggle error, configuration
    -- changed, RTR outstanding, loss / RTR due at the next tick
    signal vis_word     : std_logic_vector(slot_w_c - 1 downto 0);
    signal vis_heard    : std_logic;
    signal vis_bootup   : std_logic;
    signal vis_toggle   : std_logic;
    signal vis_changed  : std_logic;
    signal vis_out      : std_logic;
    signal vis_due_loss : std_logic;
    signal vis_due_rtr  : std_logic;
    -- the next tick is the first RTR of the slot (guarding starts); request the RTR now (first
    -- tick of a slot not visited since reset)
    signal vis_due_first : std_logic;
    signal vis_rtr_now   : std_logic;

    -- per-slot status; the time and the last NMT state of each slot are two words of the
    -- status RAM (2k: time, 2k + 1: state; written when a frame of the slot is heard, the
    -- state in the cycle after the time), heard_q marks the slots written since reset (the
    -- others read 0); st_nw_* hold the state word's write, st_fwd_* its forward to a read of it
    -- at the edge of that write
    signal alive_q    : std_logic_vector(MAX_NODES - 1 downto 0);
    signal heard_q    : std_logic_vector(MAX_NODES - 1 downto 0);
    signal st_we      : std_logic;
    signal st_nw      : std_logic;
    signal st_nw_slot : slot_t;
    signal st_nw_val  : std_logic_vector(6 downto 0);
    signal st_ram_we  : std_logic;
    signal st_waddr   : natural range 0 to 2 * MAX_NODES - 1;
    signal st_wdata   : std_logic_vector(31 downto 0);
    signal st_raddr   : natural range 0 to 2 * MAX_NODES - 1;
    signal st_rslot   : slot_t;
    signal st_rdata   : std_logic_vector(31 downto 0);
    signal st_rd_ok   : std_logic;
    signal st_rd_in   : std_logic;
    signal st_nmt_q   : std_logic;
    signal st_fwd     : std_logic;
    signal st_fwd_val : std_logic_vector(6 downto 0);
    signal lost_q     : std_logic_vector(MAX_NODES - 1 downto 0);
    signal toggle_q   : std_logic_vector(MAX_NODES - 1 downto 0);
    signal bootup_q   : std_logic_vector(MAX_NODES - 1 downto 0);
    -- per-slot engine flags: slot word written since reset, a tick not yet applied to the slot
    -- word, loss / RTR due at the next tick (from the last visit), an RTR went out unanswered
    signal valid_q     : std_logic_vector(MAX_NODES - 1 downto 0);
    signal tick_pend_q : std_logic_vector(MAX_NODES - 1 downto 0);
    signal due_loss_q  : std_logic_vector(MAX_NODES - 1 downto 0);
    signal due_rtr_q   : std_logic_vector(MAX_NODES - 1 downto 0);
    signal due_first_q : std_logic_vector(MAX_NODES - 1 downto 0);
    signal rtr_out_q   : std_logic_vector(MAX_NODES - 1 downto 0);
    -- per-slot pending transmit requests
    signal pend_rtr_q   : std_logic_vector(MAX_NODES - 1 downto 0);
    signal pend_start_q : std_logic_vector(MAX_NODES - 1 downto 0);
    signal pend_reset_q : std_logic_vector(MAX_NODES - 1 downto 0);

    -- transmit arbiter: a slot taken (its frame follows), its kind, round robin (the slots at or
    -- after the pointer), the pick: valid, one-hot slot
    signal tx_req   : std_logic;
    signal tx_kind  : tx_kind_t;
    signal rr_mask  : std_logic_vector(MAX_NODES - 1 downto 0);
    signal pick_sel : std_logic_vector(MAX_NODES - 1 downto 0);
    -- the request's slot one-hot, its frame on tx_*_o (tx_req_o)
    signal tx_sel     : std_logic_vector(MAX_NODES - 1 downto 0);
    signal tx_vld     : std_logic;
    signal pick_valid : std_logic;

    -- EMCY FIFO: entry to push (node, data, time), push request of the apply stage, refused
    -- (full), head, entries visible, an accepted push of the previous cycle, sticky loss
    signal emcy_din    : std_logic_vector(emcy_w_c - 1 downto 0);
    signal emcy_push   : std_logic;
    signal emcy_ovf    : std_logic;
    signal emcy_q      : std_logic_vector(emcy_w_c - 1 downto 0);
    signal emcy_count  : std_logic_vector(clog2(EMCY_DEPTH + 1) - 1 downto 0);
    signal emcy_push_d : std_logic;
    signal emcy_lost   : std_logic;

    -- the lowest set bit of v, one-hot (prefix ORs, no chain through the bits)

    function low_bit (v : std_logic_vector(MAX_NODES - 1 downto 0))
        return std_logic_vector is

        variable r : std_logic_vector(MAX_NODES - 1 downto 0);

    begin

        r(0) := v(0);

        for k in 1 to MAX_NODES - 1 loop

            r(k) := v(k) and not or_reduce(v(k - 1 downto 0));

        end loop;

        return r;

    end function low_bit;

    -- the index of a one-hot vector (bit b of the index: an OR over the slots with bit b set)

    function one_hot_index (v : std_logic_vector(MAX_NODES - 1 downto 0)) return slot_t is

        variable m : std_logic_vector(MAX_NODES - 1 downto 0);
        variable r : unsigned(4 downto 0);

    begin

        for b in 0 to 4 loop

            for k in 0 to MAX_NODES - 1 loop

                m(k) := to_unsigned(k, 5)(b);

            end loop;

            r(b) := or_reduce(v and m);

        end loop;

        if to_integer(r) > MAX_NODES - 1 then
            return MAX_NODES - 1; -- never for a one-hot v (keeps the range for simulation)
        end if;

        return to_integer(r);

    end function one_hot_index;

    function next_slot (s : slot_t) return slot_t is
    begin

        if s = MAX_NODES - 1 then
            return 0;
        end if;

        return s + 1;

    end function next_slot;

begin

    -- ---------------------------------------------------------------------------------------------
    -- Received frame: its time and the slot compares registered (datapath), the frame read in place
    -- ---------------------------------------------------------------------------------------------
    rx_latch_proc : process (clk_i) is
    begin

        if rising_edge(clk_i) then
            if rx_valid_i = '1' and rx_state = S_RX_IDLE then
                rx_time_q <= time_ms_i;

                for k in 0 to MAX_NODES - 1 loop

                    if cfg_node_i(7 * k + 6 downto 7 * k) /= node_none_c
                       and cfg_node_i(7 * k + 6 downto 7 * k) = node_of(rx_id_i) then
                        rx_eq_q(k) <= '1';
                    else
                        rx_eq_q(k) <= '0';
                    end if;

                end loop;

            end if;
        end if;

    end process rx_latch_proc;

    -- slot matcher: the first slot whose node-ID is the frame's (slot RAM read address in
    -- S_RX_MATCH); the compares are registered with the frame latch (rx_eq_q)
    match_proc : process (rx_eq_q) is

        variable hit_v : std_logic_vector(MAX_NODES - 1 downto 0); -- the first slot

    begin

        hit_v := low_bit(rx_eq_q);

        match_hit <= hit_v;
        match_idx <= one_hot_index(hit_v);
        match_any <= or_reduce(rx_eq_q);

    end process match_proc;

    -- ---------------------------------------------------------------------------------------------
    -- Receive sequencer: latch (rx_latch_proc), classify and find the slot (its word is read
    -- from the slot RAM), apply (the shared slot datapath / the EMCY FIFO) and report; an
    -- autostart reply is reported once tx_req_o shows a frame.
    -- Classification: RTR, SYNC and other function codes are unexpected; then a wrong DLC is
    -- malformed; then an error-control frame from a node in no slot is unexpected.
    -- ---------------------------------------------------------------------------------------------
    rx_seq_proc : process (clk_i, rst_n_i) is

        variable class_v : rx_class_t;

    begin

        if rst_n_i = '0' then
            rx_state        <= S_RX_IDLE;
            rx_class        <= RX_UNEXPECTED;
            rx_hit          <= (others => '0');
            rx_done_o       <= '0';
            rx_reply_o      <= '0';
            rx_unexpected_o <= '0';
            rx_malformed_o  <= '0';
        elsif rising_edge(clk_i) then
            rx_done_o       <= '0';
            rx_reply_o      <= '0';
            rx_unexpected_o <= '0';
            rx_malformed_o  <= '0';

            case rx_state is

                when S_RX_IDLE =>

                    if rx_valid_i = '1' then
                        rx_state <= S_RX_MATCH;
                    end if;

                when S_RX_MATCH =>

                    class_v := RX_UNEXPECTED;
                    if rx_rtr_i = '0' and node_of(rx_id_i) /= node_none_c then
                        if func_code(rx_id_i) = FC_NMT_EC_C then
                            if rx_dlc_i /= ec_dlc_c then
                                class_v := RX_MALFORMED;
                            elsif match_any = '1' then
                                class_v := RX_EC;
                            end if;
                        elsif func_code(rx_id_i) = FC_SYNC_EMCY_C then
                            if rx_dlc_i /= emcy_dlc_c then
                                class_v := RX_MALFORMED;
                            else
                                class_v := RX_EMCY;
                            end if;
                        end if;
                    end if;
                    rx_class <= class_v;
                    rx_hit   <= match_hit;
                    rx_state <= S_RX_APPLY;

                when S_RX_APPLY =>

                    if apply_reply = '1' then
                        rx_state <= S_RX_REPLY;
                    else
                        rx_done_o <= '1';
                        if rx_class = RX_UNEXPECTED or apply_unsolicited = '1' then
                            rx_unexpected_o <= '1';
                        end if;
                        if rx_class = RX_MALFORMED then
                            rx_malformed_o <= '1';
                        end if;
                        rx_state <= S_RX_IDLE;
                    end if;

                -- the start frame is on tx_req_o (or was already taken): report
                when S_RX_REPLY =>

                    if tx_vld = '1' or (pend_start_q and rx_hit) = (rx_hit'range => '0') then
                        rx_done_o  <= '1';
                        rx_reply_o <= '1';
                        rx_state   <= S_RX_IDLE;
                    end if;

            end case;

        end if;

    end process rx_seq_proc;

    -- what applying the error-control frame does: a boot-up with autostart requests NMT start,
    -- a guarding reply without an RTR out for it is unexpected (and ignored)
    rx_state_byte <= rx_data_i(6 downto 0);
    rx_toggle     <= rx_data_i(toggle_bit_c);
    rx_apply      <= '1' when rx_state = S_RX_APPLY and rx_class = RX_EC else
                     '0';

    -- (an AND/OR reduction: written with an if per slot, GHDL 2.0 --synth takes hours from
    -- MAX_NODES = 20 on)
    apply_flags_proc : process (cfg_autostart_i, cfg_mode_i, rtr_out_q, rx_apply, rx_hit,
                                rx_state_byte) is

        variable auto_v  : std_logic; -- the slot of the frame has autostart
        variable unsol_v : std_logic; -- the slot of the frame guards and has no RTR out

    begin

        auto_v  := '0';
        unsol_v := '0';

        for k in 0 to MAX_NODES - 1 loop

            auto_v := auto_v or (rx_hit(k) and cfg_autostart_i(k));

            if cfg_mode_i(2 * k + 1 downto 2 * k) = mode_guarding_c then
                unsol_v := unsol_v or (rx_hit(k) and not rtr_out_q(k));
            end if;

        end loop;

        if rx_apply = '1' and rx_state_byte = NMT_ST_BOOTUP_C then
            apply_reply       <= auto_v;
            apply_unsolicited <= '0';
        elsif rx_apply = '1' then
            apply_reply       <= '0';
            apply_unsolicited <= unsol_v;
        else
            apply_reply       <= '0';
            apply_unsolicited <= '0';
        end if;

    end process apply_flags_proc;

    -- ---------------------------------------------------------------------------------------------
    -- Slot engine. The timer state of every slot is a word in the slot RAM; one datapath
    -- (visit_proc) updates one slot per visit: a read of the word in one cycle, the visit and
    -- the write-back in the next. Visits:
    --   * frame: the error-control frame's slot, read in S_RX_MATCH, applied in S_RX_APPLY
    --     (2 edges after the edge sampling rx_valid_i, as before);
    --   * sweep: otherwise round robin over the slots, one visit every 2 cycles (a read is only
    --     started in S_RX_IDLE without rx_valid_i, so a sweep write never meets a frame read).
    -- A tick's visible effects (loss: ev_lost_o, st_lost_o, st_alive_o, reset-on-loss; RTR
    -- request) come at the tick's edge from the due bits the slot's last visit computed; its
    -- counting (timer and guard period) is applied to the slot word at the slot's next visit
    -- (tick_pend_q), at most 2 * MAX_NODES + 3 cycles per frame in between later. A frame applied
    -- at the tick's edge wins over the loss (as before: the tick is not counted for the timer).
    -- ---------------------------------------------------------------------------------------------
    one       <= '1';
    ram_raddr <= match_idx when rx_state = S_RX_MATCH else
                 sw_slot;
    rd_1h     <= match_hit when rx_state = S_RX_MATCH else
                 sw_1h;
    visit     <= sw_phase or rx_apply;

    slot_ram_inst : entity work.canopen_sdp_ram
        generic map (
            DEPTH => MAX_NODES,
            WIDTH => slot_w_c
        )
        port map (
            clk_i   => clk_i,
            we_i    => visit,
            waddr_i => eng_slot,
            wdata_i => vis_word,
            re_i    => one,
            raddr_i => ram_raddr,
            rdata_o => ram_rdata
        );

    eng_proc : process (clk_i, rst_n_i) is
    begin

        if rst_n_i = '0' then
            sw_phase <= '0';
            sw_slot  <= 0;
            sw_1h    <= (0 => '1', others => '0');
            eng_slot <= 0;
        elsif rising_edge(clk_i) then
            if sw_phase = '1' then
                sw_phase <= '0';
                sw_slot  <= next_slot(sw_slot);

                for k in 0 to MAX_NODES - 1 loop

                    sw_1h((k + 1) mod MAX_NODES) <= sw_1h(k);

                end loop;

            elsif rx_state = S_RX_IDLE and rx_valid_i = '0' then
                sw_phase <= '1';
                eng_slot <= sw_slot;
            end if;
            if rx_state = S_RX_MATCH then
                eng_slot <= match_idx;
            end if;
        end if;

    end process eng_proc;

    -- configuration of the slot read in this cycle, registered with the read for its visit
    -- (an AND-OR with the one-hot slot: no index decoding on the matcher's path)
    cfg_mux_proc : process (cfg_mode_i, cfg_node_i, cfg_tl_ok_i, rd_1h, valid_q) is

        variable node_v : node_id_t;
        variable mode_v : std_logic_vector(1 downto 0);

    begin

        node_v := (others => '0');
        mode_v := (others => '0');

        for k in 0 to MAX_NODES - 1 loop

            if rd_1h(k) = '1' then
                node_v := node_v or cfg_node_i(7 * k + 6 downto 7 * k);
                mode_v := mode_v or cfg_mode_i(2 * k + 1 downto 2 * k);
            end if;

        end loop;

        m_node  <= node_v;
        m_mode  <= mode_v;
        m_ok    <= or_reduce(rd_1h and cfg_tl_ok_i);
        m_valid <= or_reduce(rd_1h and valid_q);

    end process cfg_mux_proc;

    -- (datapath registers: valid only in the visit cycle, no reset needed)
    cfg_reg_proc : process (clk_i) is
    begin

        if rising_edge(clk_i) then
            v_node   <= m_node;
            v_mode   <= m_mode;
            v_hb_cfg <= m_node /= node_none_c and m_mode = mode_heartbeat_c and m_ok = '1';
            v_ng_cfg <= m_node /= node_none_c and m_mode = mode_guarding_c and m_ok = '1';
            v_valid  <= m_valid;
        end if;

    end process cfg_reg_proc;

    -- time RAM: written by the host block (NODE_TIME), read with the slot word (ram_raddr), so
    -- its word belongs to eng_slot in the visit cycle, like the registers above. A slot not
    -- written since reset reads as time 0 (v_hb_cfg / v_ng_cfg are false: time and factor
    -- are not used then)
    tl_we    <= cfg_tl_we_i when unsigned(cfg_tl_slot_i) < MAX_NODES else
                '0';
    tl_waddr <= to_integer(unsigned(cfg_tl_slot_i)) when unsigned(cfg_tl_slot_i) < MAX_NODES else
                0;

    tl_wdata(tl_time_c + 15 downto tl_time_c) <= cfg_tl_time_i;
    tl_wdata(tl_life_c + 7 downto tl_life_c)  <= cfg_tl_life_i;
    tl_wdata(tl_tnz_c)                        <= or_reduce(cfg_tl_time_i);
    tl_wdata(tl_tle1_c)                       <= not or_reduce(cfg_tl_time_i(15 downto 1));
    tl_wdata(tl_lnz_c)                        <= or_reduce(cfg_tl_life_i);

    tl_ram_inst : entity work.canopen_sdp_ram
        generic map (
            DEPTH => MAX_NODES,
            WIDTH => tl_w_c
        )
        port map (
            clk_i   => clk_i,
            we_i    => tl_we,
            waddr_i => tl_waddr,
            wdata_i => tl_wdata,
            re_i    => one,
            raddr_i => ram_raddr,
            rdata_o => tl_rdata
        );

    v_time     <= unsigned(tl_rdata(tl_time_c + 15 downto tl_time_c));
    v_life     <= unsigned(tl_rdata(tl_life_c + 7 downto tl_life_c));
    v_time_le1 <= tl_rdata(tl_tle1_c) = '1';
    v_hb       <= v_hb_cfg and tl_rdata(tl_tnz_c) = '1';
    v_guard    <= v_ng_cfg and tl_rdata(tl_tnz_c) = '1';
    v_sup      <= v_hb or (v_guard and tl_rdata(tl_lnz_c) = '1');

    -- ---------------------------------------------------------------------------------------------
    -- The shared slot datapath: in this order, frame taken by the FSM, received frame, tick(s)
    -- not yet applied, (re)load of the loss timer, configuration.
    -- Loss timer: remaining ms r = sub (heartbeat, fac = 0) or r = (fac - 1) * G + sub
    -- (guarding, fac = life time factor at a reload, sub wraps from 1 to G while fac > 1).
    -- A tick with r = 0 is the loss, so a reload with T (or G x factor) expires at the
    -- (T+1)-th tick after it.
    -- ---------------------------------------------------------------------------------------------
    visit_proc : process (eng_slot, ram_rdata, rtr_out_q, rx_apply, rx_state_byte, rx_toggle,
                          tick_ms_i, tick_pend_q, tx_ack_i, tx_kind, tx_sel, tx_vld, v_guard,
                          v_hb, v_life, v_mode, v_node, v_sup, v_time, v_time_le1, v_valid) is

        variable word_v   : std_logic_vector(slot_w_c - 1 downto 0);
        variable hb_v     : boolean;   -- heartbeat consumer with T /= 0
        variable guard_v  : boolean;   -- node guarding with G /= 0
        variable sup_v    : boolean;   -- a loss can be detected
        variable heard_v  : boolean;   -- the node was heard in this visit
        variable reload_v : boolean;   -- (re)start the loss timer
        variable tick_v   : boolean;   -- a tick to count
        variable sub_v    : unsigned(15 downto 0);
        variable fac_v    : unsigned(7 downto 0);
        variable gcnt_v   : unsigned(15 downto 0);
        variable armed_v  : std_logic;
        variable run_v    : std_logic;
        variable exp_v    : std_logic;
        variable out_q_v  : std_logic; -- RTR outstanding before this cycle
        variable out_v    : std_logic;
        variable chg_v    : boolean;   -- node-ID or mode changed since the last visit
        variable cnt_v    : boolean;   -- the tick is counted by the loss timer

    begin

        -- a slot not visited since reset: not armed, not running, toggle 0 (the counters are
        -- only read while armed / running, so they need no masking)
        word_v            := ram_rdata;
        word_v(w_armed_c) := ram_rdata(w_armed_c) and v_valid;
        word_v(w_run_c)   := ram_rdata(w_run_c) and v_valid;
        word_v(w_exp_c)   := ram_rdata(w_exp_c) and v_valid;

        sub_v   := unsigned(word_v(w_sub_c + 15 downto w_sub_c));
        fac_v   := unsigned(word_v(w_fac_c + 7 downto w_fac_c));
        gcnt_v  := unsigned(word_v(w_gcnt_c + 15 downto w_gcnt_c));
        armed_v := word_v(w_armed_c);
        run_v   := word_v(w_run_c);
        exp_v   := word_v(w_exp_c);
        out_q_v := rtr_out_q(eng_slot);
        out_v   := out_q_v;

        hb_v     := v_hb;
        guard_v  := v_guard;
        sup_v    := v_sup;
        tick_v   := tick_ms_i = '1' or tick_pend_q(eng_slot) = '1';
        heard_v  := false;
        reload_v := false;

        vis_bootup  <= '0';
        vis_toggle  <= '0';
        vis_rtr_now <= '0';

        -- the FSM took this slot's RTR
        if tx_vld = '1' and tx_ack_i = '1' and tx_sel(eng_slot) = '1' and tx_kind = TX_RTR then
            out_v := '1';
        end if;

        -- error-control frame from this slot's node
        if rx_apply = '1' then
            if rx_state_byte = NMT_ST_BOOTUP_C then
                -- boot-up: record it, restart the toggle rule; heartbeat monitoring restarts
                -- with the first heartbeat, guarding keeps polling. An RTR already taken for
                -- transmission stays outstanding: the booted node answers it (toggle 0), and
                -- ignoring that reply would leave the expectation one step behind
                heard_v    := true;
                vis_bootup <= '1';
                exp_v      := '0';
                armed_v    := '0';
                reload_v   := guard_v and run_v = '1';
            elsif v_mode = mode_guarding_c then
                -- guarding reply: only as the answer to an RTR that went out
                if out_q_v = '1' then
                    heard_v  := true;
                    out_v    := '0';
                    reload_v := run_v = '1';
                    if rx_toggle /= exp_v then
                        vis_toggle <= '1';
                    end if;
                    -- alternate; after an error resynchronise to the received bit
                    exp_v := not rx_toggle;
                end if;
            else
                -- heartbeat (or a slot without supervision: state only)
                heard_v  := true;
                reload_v := hb_v;
            end if;
        end if;

        -- tick: loss timer (the loss itself was reported at the tick from the due bit), then
        -- the guard period (RTR every G ticks from the first tick after guarding is enabled)
        if tick_v then
            if armed_v = '1' and not heard_v then
                if sub_v = 0 then
                    armed_v := '0';
                elsif sub_v = 1 and fac_v > 1 then
                    sub_v := v_time;
                    fac_v := fac_v - 1;
                else
                    sub_v := sub_v - 1;
                end if;
            end if;
            if guard_v then
                if run_v = '0' or gcnt_v <= 1 then
                    gcnt_v := v_time;
                else
                    gcnt_v := gcnt_v - 1;
                end if;
                -- first request: toggle expected 0, life timer started (no RTR outstanding: set
                -- at the tick's edge by slot_proc from due_first_q, here for a tick at this edge;
                -- a slot not visited since reset had no due bits: its first RTR is requested now)
                if run_v = '0' then
                    run_v    := '1';
                    exp_v    := '0';
                    reload_v := true;
                    if tick_ms_i = '1' or v_valid = '0' then
                        out_v := '0';
                    end if;
                    if v_valid = '0' then
                        vis_rtr_now <= '1';
                    end if;
                end if;
            end if;
        end if;

        if reload_v then
            armed_v := '1';
            sub_v   := v_time;
            if guard_v then
                fac_v := v_life;
            else
                fac_v := (others => '0');
            end if;
        end if;

        -- supervision switched off, or the slot re-configured: restart it
        if not guard_v then
            run_v  := '0';
            gcnt_v := (others => '0');
        end if;

        if not sup_v then
            armed_v := '0';
        end if;

        -- (a slot never visited since reset starts from the all-zero word: nothing to restart)
        vis_changed <= '0';

        if v_valid = '1'
           and (v_node /= word_v(w_node_c + 6 downto w_node_c)
                  or v_mode /= word_v(w_mode_c + 1 downto w_mode_c)) then
            vis_changed <= '1';
            armed_v     := '0';
            run_v       := '0';
            exp_v       := '0';
            out_v       := '0';
        end if;

        if heard_v then
            vis_heard <= '1';
        else
            vis_heard <= '0';
        end if;

        vis_out <= out_v;
        -- due bits of the next tick: armed and sub = 0, guarding and (run = 0 or gcnt <= 1), as
        -- functions of the word read (short paths): a reload (sub = T or G, never 0) or a
        -- restart clears the loss; a counted tick leaves sub = 0 only from sub = 1 with fac <= 1
        -- and gcnt <= 1 only from gcnt = 2 or a reload with G <= 1
        chg_v        := v_valid = '1'
                        and (v_node /= word_v(w_node_c + 6 downto w_node_c)
                               or v_mode /= word_v(w_mode_c + 1 downto w_mode_c));
        cnt_v        := tick_v and word_v(w_armed_c) = '1' and not heard_v;
        vis_due_loss <= '0';

        if sup_v and not reload_v and not chg_v and not (rx_apply = '1'
                                                         and rx_state_byte = NMT_ST_BOOTUP_C) then
            if cnt_v then
                if unsigned(word_v(w_sub_c + 15 downto w_sub_c)) = 1
                   and unsigned(word_v(w_fac_c + 7 downto w_fac_c)) <= 1 then
                    vis_due_loss <= '1';
                end if;
            elsif word_v(w_armed_c) = '1' and unsigned(word_v(w_sub_c + 15 downto w_sub_c)) = 0 then
                vis_due_loss <= '1';
            end if;
        end if;

        vis_due_rtr   <= '0';
        vis_due_first <= '0';

        if guard_v then
            if chg_v then
                vis_due_rtr   <= '1';
                vis_due_first <= '1';
            elsif tick_v then
                if word_v(w_run_c) = '0'
                   or unsigned(word_v(w_gcnt_c + 15 downto w_gcnt_c)) <= 1 then
                    if v_time_le1 then
                        vis_due_rtr <= '1';
                    end if;
                elsif unsigned(word_v(w_gcnt_c + 15 downto w_gcnt_c)) = 2 then
                    vis_due_rtr <= '1';
                end if;
            elsif word_v(w_run_c) = '0' then
                vis_due_rtr   <= '1';
                vis_due_first <= '1';
            elsif unsigned(word_v(w_gcnt_c + 15 downto w_gcnt_c)) <= 1 then
                vis_due_rtr <= '1';
            end if;
        end if;

        vis_word                                <= (others => '0');
        vis_word(w_sub_c + 15 downto w_sub_c)   <= std_logic_vector(sub_v);
        vis_word(w_fac_c + 7 downto w_fac_c)    <= std_logic_vector(fac_v);
        vis_word(w_gcnt_c + 15 downto w_gcnt_c) <= std_logic_vector(gcnt_v);
        vis_word(w_armed_c)                     <= armed_v;
        vis_word(w_run_c)                       <= run_v;
        vis_word(w_exp_c)                       <= exp_v;
        vis_word(w_node_c + 6 downto w_node_c)  <= v_node;
        vis_word(w_mode_c + 1 downto w_mode_c)  <= v_mode;

    end process visit_proc;

    -- ---------------------------------------------------------------------------------------------
    -- Per-slot flags and status (static index k), in this order: host clear, frame taken by the
    -- FSM, tick (loss and RTR from the due bits; a frame of the slot applied at this edge wins
    -- over the loss), visit of the slot (frame results, due bits, configuration restart).
    -- ---------------------------------------------------------------------------------------------
    slot_proc : process (clk_i, rst_n_i) is
    begin

        if rst_n_i = '0' then
            alive_q      <= (others => '0');
            heard_q      <= (others => '0');
            lost_q       <= (others => '0');
            toggle_q     <= (others => '0');
            bootup_q     <= (others => '0');
            valid_q      <= (others => '0');
            tick_pend_q  <= (others => '0');
            due_loss_q   <= (others => '0');
            due_rtr_q    <= (others => '0');
            due_first_q  <= (others => '0');
            rtr_out_q    <= (others => '0');
            pend_rtr_q   <= (others => '0');
            pend_start_q <= (others => '0');
            pend_reset_q <= (others => '0');
            ev_lost_o    <= (others => '0');
            ev_toggle_o  <= (others => '0');
            ev_bootup_o  <= (others => '0');
        elsif rising_edge(clk_i) then
            ev_lost_o   <= (others => '0');
            ev_toggle_o <= (others => '0');
            ev_bootup_o <= (others => '0');

            for k in 0 to MAX_NODES - 1 loop

                -- host clears the sticky bits (an event in the same cycle sets them again)
                if st_clear_i(k) = '1' then
                    lost_q(k)   <= '0';
                    toggle_q(k) <= '0';
                    bootup_q(k) <= '0';
                end if;

                -- the FSM took this slot's frame
                if tx_vld = '1' and tx_ack_i = '1' and tx_sel(k) = '1' then

                    case tx_kind is

                        when TX_RESET =>

                            pend_reset_q(k) <= '0';

                        when TX_START =>

                            pend_start_q(k) <= '0';

                        when TX_RTR =>

                            pend_rtr_q(k) <= '0';
                            rtr_out_q(k)  <= '1';

                    end case;

                end if;

                -- ms tick
                if tick_ms_i = '1' then
                    tick_pend_q(k) <= '1';
                    if due_loss_q(k) = '1'
                       and not (rx_apply = '1' and eng_slot = k and vis_heard = '1') then
                        alive_q(k)   <= '0';
                        lost_q(k)    <= '1';
                        ev_lost_o(k) <= '1';
                        if cfg_reset_on_loss_i(k) = '1' then
                            pend_reset_q(k) <= '1';
                        end if;
                    end if;
                    if due_rtr_q(k) = '1' then
                        pend_rtr_q(k) <= '1';
                    end if;
                    -- first request of the slot: no RTR outstanding (a frame taken in this
                    -- cycle included)
                    if due_first_q(k) = '1' then
                        rtr_out_q(k) <= '0';
                    end if;
                end if;

                -- visit of this slot
                if visit = '1' and eng_slot = k then
                    valid_q(k)     <= '1';
                    tick_pend_q(k) <= '0';
                    due_loss_q(k)  <= vis_due_loss;
                    due_rtr_q(k)   <= vis_due_rtr;
                    due_first_q(k) <= vis_due_first;
                    rtr_out_q(k)   <= vis_out;
                    if vis_heard = '1' then
                        heard_q(k) <= '1'; -- state and time: the status RAM (st_we)
                        alive_q(k) <= '1';
                    end if;
                    if vis_bootup = '1' then
                        bootup_q(k)     <= '1';
                        ev_bootup_o(k)  <= '1';
                        pend_reset_q(k) <= '0';
                        if cfg_autostart_i(k) = '1' then
                            pend_start_q(k) <= '1';
                        end if;
                    end if;
                    if vis_toggle = '1' then
                        toggle_q(k)    <= '1';
                        ev_toggle_o(k) <= '1';
                    end if;
                    if vis_rtr_now = '1' then
                        pend_rtr_q(k) <= '1';
                    end if;
                    if vis_changed = '1' then
                        alive_q(k)      <= '0';
                        pend_rtr_q(k)   <= '0';
                        pend_start_q(k) <= '0';
                        pend_reset_q(k) <= '0';
                    end if;
                end if;

            end loop;

        end if;

    end process slot_proc;

    -- ---------------------------------------------------------------------------------------------
    -- Transmit arbiter: the first slot with a pending request at or after the round-robin
    -- pointer (rr_mask: the slots at or after it), else the first one; within a slot reset-node
    -- before start before RTR. One-hot selection (lowest set bit by prefix ORs): no priority
    -- chain over the slots.
    -- ---------------------------------------------------------------------------------------------
    pick_proc : process (pend_reset_q, pend_rtr_q, pend_start_q, rr_mask) is

        variable any_v : std_logic_vector(MAX_NODES - 1 downto 0); -- slots with a request
        variable hi_v  : std_logic_vector(MAX_NODES - 1 downto 0); -- ... at or after the pointer
        variable sh_v  : std_logic_vector(MAX_NODES - 1 downto 0); -- first of hi_v, one-hot
        variable sl_v  : std_logic_vector(MAX_NODES - 1 downto 0); -- first of any_v, one-hot
        variable sel_v : std_logic_vector(MAX_NODES - 1 downto 0); -- chosen slot, one-hot

    begin

        any_v := pend_rtr_q or pend_start_q or pend_reset_q;
        hi_v  := any_v and rr_mask;
        sh_v  := low_bit(hi_v);
        sl_v  := low_bit(any_v);

        if or_reduce(hi_v) = '1' then
            sel_v := sh_v;
        else
            sel_v := sl_v;
        end if;

        pick_sel   <= sel_v;
        pick_valid <= or_reduce(any_v);

    end process pick_proc;

    tx_arb_proc : process (clk_i, rst_n_i) is

        variable seen_v : std_logic; -- a slot below k was served (or the last one)

    begin

        if rst_n_i = '0' then
            tx_req  <= '0';
            tx_sel  <= (others => '0');
            rr_mask <= (others => '1');
        elsif rising_edge(clk_i) then
            if tx_req = '1' then
                if tx_vld = '1' and tx_ack_i = '1' then
                    tx_req <= '0';
                    -- the slots after the one served (all of them after the last slot)
                    seen_v := tx_sel(MAX_NODES - 1);

                    for k in 0 to MAX_NODES - 1 loop

                        rr_mask(k) <= seen_v;
                        seen_v     := seen_v or tx_sel(k);

                    end loop;

                end if;
            elsif pick_valid = '1' then
                tx_req <= '1';
                tx_sel <= pick_sel;
            end if;
        end if;

    end process tx_arb_proc;

    -- the kind (reset-node before start before RTR) and the frame of the slot the arbiter took,
    -- registered one cycle after it (the round-robin pick and the frame fields are not one
    -- path); tx_req_o rises with them
    tx_frame_proc : process (clk_i, rst_n_i) is

        variable node_v : node_id_t;
        variable kind_v : tx_kind_t;

    begin

        if rst_n_i = '0' then
            tx_vld  <= '0';
            tx_kind <= TX_RTR;
        elsif rising_edge(clk_i) then
            if tx_req = '0' or tx_ack_i = '1' then
                tx_vld <= '0';
            elsif tx_vld = '0' then
                tx_vld <= '1';
            end if;
            if tx_req = '1' and tx_vld = '0' then
                if or_reduce(tx_sel and pend_reset_q) = '1' then
                    tx_kind <= TX_RESET;
                elsif or_reduce(tx_sel and pend_start_q) = '1' then
                    tx_kind <= TX_START;
                else
                    tx_kind <= TX_RTR;
                end if;
            end if;
        end if;

        if rising_edge(clk_i) then
            if tx_req = '1' and tx_vld = '0' then
                node_v := node_none_c;
                if or_reduce(tx_sel and pend_reset_q) = '1' then
                    kind_v := TX_RESET;
                elsif or_reduce(tx_sel and pend_start_q) = '1' then
                    kind_v := TX_START;
                else
                    kind_v := TX_RTR;
                end if;

                for k in 0 to MAX_NODES - 1 loop

                    if tx_sel(k) = '1' then
                        node_v := node_v or cfg_node_i(7 * k + 6 downto 7 * k);
                    end if;

                end loop;

                tx_data_o <= (others => '0');

                case kind_v is

                    when TX_RTR =>

                        tx_id_o  <= cob_id(FC_NMT_EC_C, node_v);
                        tx_rtr_o <= '1';
                        tx_dlc_o <= ec_dlc_c;

                    when TX_START =>

                        tx_id_o                <= COB_NMT_C;
                        tx_rtr_o               <= '0';
                        tx_dlc_o               <= nmt_dlc_c;
                        tx_data_o(7 downto 0)  <= NMT_CS_START_C;
                        tx_data_o(15 downto 8) <= '0' & node_v;

                    when TX_RESET =>

                        tx_id_o                <= COB_NMT_C;
                        tx_rtr_o               <= '0';
                        tx_dlc_o               <= nmt_dlc_c;
                        tx_data_o(7 downto 0)  <= NMT_CS_RESET_NODE_C;
                        tx_data_o(15 downto 8) <= '0' & node_v;

                end case;

            end if;
        end if;

    end process tx_frame_proc;

    tx_req_o <= tx_vld;

    -- ---------------------------------------------------------------------------------------------
    -- EMCY FIFO (canopen_fifo: first-word fall-through on block RAM). An EMCY (the RX_EMCY class
    -- of rx_seq_proc, here from the frame inputs) is pushed at the edge that samples rx_valid_i;
    -- it is counted for the host (emcy_count_o) one cycle after its write, when the head can
    -- show it; ev_emcy_o comes with that count. A push into a full FIFO is refused (ovf) and sets
    -- emcy_lost (a pop in the same cycle makes room).
    -- ---------------------------------------------------------------------------------------------
    emcy_push <= '1' when rx_state = S_RX_IDLE and rx_valid_i = '1' and rx_rtr_i = '0'
                          and func_code(rx_id_i) = FC_SYNC_EMCY_C
                          and node_of(rx_id_i) /= node_none_c and rx_dlc_i = emcy_dlc_c else
                 '0';
    emcy_din  <= node_of(rx_id_i) & rx_data_i & time_ms_i;

    emcy_fifo_inst : entity work.canopen_fifo
        generic map (
            WIDTH => emcy_w_c,
            DEPTH => EMCY_DEPTH
        )
        port map (
            clk_i   => clk_i,
            rst_n_i => rst_n_i,
            push_i  => emcy_push,
            data_i  => emcy_din,
            full_o  => open,
            ovf_o   => emcy_ovf,
            pop_i   => emcy_pop_i,
            empty_o => open,
            data_o  => emcy_q,
            count_o => emcy_count
        );

    emcy_ctrl_proc : process (clk_i, rst_n_i) is
    begin

        if rst_n_i = '0' then
            emcy_push_d <= '0';
            emcy_lost   <= '0';
            ev_emcy_o   <= '0';
        elsif rising_edge(clk_i) then
            emcy_push_d <= emcy_push and not emcy_ovf;
            -- the event coincides with the entry becoming visible in emcy_count
            ev_emcy_o <= emcy_push_d;
            if emcy_clear_i = '1' then
                emcy_lost <= '0';
            end if;
            if emcy_ovf = '1' then
                emcy_lost <= '1';
            end if;
        end if;

    end process emcy_ctrl_proc;

    emcy_count_o <= std_logic_vector(resize(unsigned(emcy_count), 7));
    emcy_lost_o  <= emcy_lost;
    emcy_node_o  <= emcy_q(emcy_w_c - 1 downto emcy_w_c - 7);
    emcy_data_o  <= emcy_q(95 downto 32);
    emcy_time_o  <= emcy_q(31 downto 0);

    -- ---------------------------------------------------------------------------------------------
    -- Status RAM: time last heard (word 2k) and last NMT state (word 2k + 1, bits 6..0) per slot,
    -- written by the visit of a heard frame (the time) and in the next cycle (the state), read by
    -- the host (canopen_host_regs) through st_rd_slot_i / st_rd_nmt_i, data one cycle later. A
    -- read at the edge of a write returns the word before it, except the state word at the edge
    -- of its write, which is forwarded (the slot already counts as heard then). One RAM of
    -- 2 * MAX_NODES words: the 7-bit state alone is too small for a block RAM (yosys keeps it in
    -- logic), a {state, time} word too wide for one.
    -- ---------------------------------------------------------------------------------------------
    st_we <= visit and vis_heard;

    st_nw_proc : process (clk_i, rst_n_i) is
    begin

        if rst_n_i = '0' then
            st_nw <= '0';
        elsif rising_edge(clk_i) then
            st_nw <= st_we;
        end if;

    end process st_nw_proc;

    -- datapath, qualified by st_nw (no reset)
    st_nw_data_proc : process (clk_i) is
    begin

        if rising_edge(clk_i) then
            if st_we = '1' then
                st_nw_slot <= eng_slot;
                st_nw_val  <= rx_state_byte;
            end if;
        end if;

    end process st_nw_data_proc;

    -- the state word's bits 31..7 take the time's bits (no multiplexer for them; a read of the
    -- state word zero-extends bits 6..0)
    st_ram_we <= st_we or st_nw;
    st_waddr  <= 2 * eng_slot when st_we = '1' else
                 2 * st_nw_slot + 1;
    st_wdata  <= rx_time_q when st_we = '1' else
                 rx_time_q(31 downto 7) & st_nw_val;

    st_rd_in <= '1' when unsigned(st_rd_slot_i) < MAX_NODES else
                '0';
    st_rslot <= to_integer(unsigned(st_rd_slot_i)) when st_rd_in = '1' else
                0;
    st_raddr <= 2 * st_rslot + bit_int(st_rd_nmt_i);

    st_ram_inst : entity work.canopen_sdp_ram
        generic map (
            DEPTH => 2 * MAX_NODES,
            WIDTH => 32
        )
        port map (
            clk_i   => clk_i,
            we_i    => st_ram_we,
            waddr_i => st_waddr,
            wdata_i => st_wdata,
            re_i    => one,
            raddr_i => st_raddr,
            rdata_o => st_rdata
        );

    -- the slot was heard since reset (sampled with the RAM read: before a write at that edge);
    -- the word read; the state word being written at the read's edge
    st_ok_proc : process (clk_i, rst_n_i) is
    begin

        if rst_n_i = '0' then
            st_rd_ok <= '0';
            st_nmt_q <= '0';
            st_fwd   <= '0';
        elsif rising_edge(clk_i) then
            st_rd_ok <= st_rd_in and heard_q(st_rslot);
            st_nmt_q <= st_rd_nmt_i;
            if st_nw = '1' and st_nw_slot = st_rslot and st_rd_nmt_i = '1' then
                st_fwd <= '1';
            else
                st_fwd <= '0';
            end if;
        end if;

    end process st_ok_proc;

    -- datapath, qualified by st_fwd (no reset)
    st_fwd_proc : process (clk_i) is
    begin

        if rising_edge(clk_i) then
            st_fwd_val <= st_nw_val;
        end if;

    end process st_fwd_proc;

    st_rd_data_o <= (31 downto 7 => '0') & st_fwd_val when st_rd_ok = '1' and st_fwd = '1' else
                    (31 downto 7 => '0') & st_rdata(6 downto 0) when st_rd_ok = '1'
                                                                     and st_nmt_q = '1' else
                    st_rdata when st_rd_ok = '1' else
                    (others => '0');

    -- simulation only: the state word's write never meets the next heard visit (a received
    -- frame is applied at most once in many cycles: the FSM dispatches one frame at a time)
    -- pragma translate_off
    st_nw_check_proc : process (clk_i) is
    begin

        if rising_edge(clk_i) then
            assert not (st_we = '1' and st_nw = '1')
                report "canopen_node_monitor: a heard visit in the cycle after another"
                severity failure;
        end if;

    end process st_nw_check_proc;

    -- pragma translate_on

    st_alive_o  <= alive_q;
    st_lost_o   <= lost_q;
    st_toggle_o <= toggle_q;
    st_bootup_o <= bootup_q;

end architecture rtl;
