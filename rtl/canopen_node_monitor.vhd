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
--   while a frame is in process. The frames this block wants to send (guarding RTRs, NMT start
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
        cfg_node_i          : in    std_logic_vector(7 * MAX_NODES - 1 downto 0);  -- node-ID
        cfg_mode_i          : in    std_logic_vector(2 * MAX_NODES - 1 downto 0);  -- 01 hb, 10 ng
        cfg_time_i          : in    std_logic_vector(16 * MAX_NODES - 1 downto 0); -- T or G [ms]
        cfg_life_i          : in    std_logic_vector(8 * MAX_NODES - 1 downto 0);  -- life factor
        cfg_autostart_i     : in    std_logic_vector(MAX_NODES - 1 downto 0);      -- start on boot
        cfg_reset_on_loss_i : in    std_logic_vector(MAX_NODES - 1 downto 0);      -- reset on loss
        -- per-slot status
        st_nmt_o    : out   std_logic_vector(7 * MAX_NODES - 1 downto 0);  -- last NMT state
        st_alive_o  : out   std_logic_vector(MAX_NODES - 1 downto 0);      -- heard, not expired
        st_lost_o   : out   std_logic_vector(MAX_NODES - 1 downto 0);      -- sticky: loss
        st_toggle_o : out   std_logic_vector(MAX_NODES - 1 downto 0);      -- sticky: toggle error
        st_bootup_o : out   std_logic_vector(MAX_NODES - 1 downto 0);      -- sticky: boot-up seen
        st_last_o   : out   std_logic_vector(32 * MAX_NODES - 1 downto 0); -- time last heard
        st_clear_i  : in    std_logic_vector(MAX_NODES - 1 downto 0);      -- clear sticky bits
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

    function check_config return boolean is
    begin

        assert MAX_NODES <= 32 and EMCY_DEPTH >= 2 and EMCY_DEPTH <= 64
            report "canopen_node_monitor: MAX_NODES must be 1..32, EMCY_DEPTH 2..64"
            severity failure;
        report "canopen_node_monitor: " & integer'image(MAX_NODES) & " slots, EMCY FIFO "
               & integer'image(EMCY_DEPTH) & " x " & integer'image(emcy_w_c) & " bits"
            severity note;
        return true;

    end function check_config;

    constant config_ok_c : boolean := check_config;

    -- ---------------------------------------------------------------------------------------------
    -- Types
    -- ---------------------------------------------------------------------------------------------

    subtype slot_t is natural range 0 to MAX_NODES - 1;

    subtype emcy_ptr_t is natural range 0 to EMCY_DEPTH - 1;

    type vec7_array_t is array (0 to MAX_NODES - 1) of std_logic_vector(6 downto 0);

    type vec32_array_t is array (0 to MAX_NODES - 1) of std_logic_vector(31 downto 0);

    type u16_array_t is array (0 to MAX_NODES - 1) of unsigned(15 downto 0);

    type u8_array_t is array (0 to MAX_NODES - 1) of unsigned(7 downto 0);

    type emcy_mem_t is array (0 to EMCY_DEPTH - 1) of std_logic_vector(emcy_w_c - 1 downto 0);

    -- receive sequencer

    type rx_state_t is (
        S_RX_IDLE,  -- wait for rx_valid_i
        S_RX_MATCH, -- classify the frame, find the slot of its node
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
    -- received frame, latched with rx_valid_i (datapath) with time_ms_i at that moment
    signal rx_id_q   : cob_id_t;
    signal rx_rtr_q  : std_logic;
    signal rx_dlc_q  : std_logic_vector(3 downto 0);
    signal rx_data_q : std_logic_vector(63 downto 0);
    signal rx_time_q : std_logic_vector(31 downto 0);
    -- receive sequencer state, class of the frame, one-hot slot of its node (first match)
    signal rx_state : rx_state_t;
    signal rx_class : rx_class_t;
    signal rx_hit   : std_logic_vector(MAX_NODES - 1 downto 0);
    -- apply stage: error-control frame, its state byte and toggle bit, what it leads to
    signal rx_apply          : std_logic;
    signal rx_state_byte     : std_logic_vector(6 downto 0);
    signal rx_toggle         : std_logic;
    signal apply_reply       : std_logic;
    signal apply_unsolicited : std_logic;

    -- configuration seen in the previous cycle (a change of node-ID or mode restarts a slot)
    signal cfg_node_q : std_logic_vector(7 * MAX_NODES - 1 downto 0);
    signal cfg_mode_q : std_logic_vector(2 * MAX_NODES - 1 downto 0);

    -- per-slot status
    signal nmt_q    : vec7_array_t;
    signal last_q   : vec32_array_t;
    signal alive_q  : std_logic_vector(MAX_NODES - 1 downto 0);
    signal lost_q   : std_logic_vector(MAX_NODES - 1 downto 0);
    signal toggle_q : std_logic_vector(MAX_NODES - 1 downto 0);
    signal bootup_q : std_logic_vector(MAX_NODES - 1 downto 0);
    -- per-slot loss timer: remaining ms = fac * G + sub (heartbeat: fac = 0, sub <= T)
    signal armed_q : std_logic_vector(MAX_NODES - 1 downto 0);
    signal sub_q   : u16_array_t;
    signal fac_q   : u8_array_t;
    -- per-slot guarding: running, ms to the next RTR, expected toggle, an RTR went out unanswered
    signal grd_run_q : std_logic_vector(MAX_NODES - 1 downto 0);
    signal gcnt_q    : u16_array_t;
    signal exp_tog_q : std_logic_vector(MAX_NODES - 1 downto 0);
    signal rtr_out_q : std_logic_vector(MAX_NODES - 1 downto 0);
    -- per-slot pending transmit requests
    signal pend_rtr_q   : std_logic_vector(MAX_NODES - 1 downto 0);
    signal pend_start_q : std_logic_vector(MAX_NODES - 1 downto 0);
    signal pend_reset_q : std_logic_vector(MAX_NODES - 1 downto 0);

    -- transmit arbiter: frame presented, its slot and kind, round-robin start slot
    signal tx_req     : std_logic;
    signal tx_slot    : slot_t;
    signal tx_kind    : tx_kind_t;
    signal rr_ptr     : slot_t;
    signal pick_valid : std_logic;
    signal pick_slot  : slot_t;
    signal pick_kind  : tx_kind_t;

    -- EMCY FIFO: block RAM with a synchronous read of the next head, write/read pointers,
    -- entries readable by the host, a push of the previous cycle (readable from now on)
    signal emcy_mem    : emcy_mem_t;
    signal emcy_q      : std_logic_vector(emcy_w_c - 1 downto 0);
    signal emcy_wr     : emcy_ptr_t;
    signal emcy_rd     : emcy_ptr_t;
    signal emcy_rd_nxt : emcy_ptr_t;
    signal emcy_count  : natural range 0 to EMCY_DEPTH;
    signal emcy_push_d : std_logic;
    signal emcy_fill   : natural range 0 to EMCY_DEPTH + 1;
    signal emcy_push   : std_logic;
    signal emcy_pop    : std_logic;
    signal emcy_lost   : std_logic;

    function next_ptr (p : emcy_ptr_t) return emcy_ptr_t is
    begin

        if p = EMCY_DEPTH - 1 then
            return 0;
        end if;

        return p + 1;

    end function next_ptr;

    function next_slot (s : slot_t) return slot_t is
    begin

        if s = MAX_NODES - 1 then
            return 0;
        end if;

        return s + 1;

    end function next_slot;

begin

    -- ---------------------------------------------------------------------------------------------
    -- Received frame latch (datapath)
    -- ---------------------------------------------------------------------------------------------
    rx_latch_proc : process (clk_i) is
    begin

        if rising_edge(clk_i) then
            if rx_valid_i = '1' and rx_state = S_RX_IDLE then
                rx_id_q   <= rx_id_i;
                rx_rtr_q  <= rx_rtr_i;
                rx_dlc_q  <= rx_dlc_i;
                rx_data_q <= rx_data_i;
                rx_time_q <= time_ms_i;
            end if;
        end if;

    end process rx_latch_proc;

    -- ---------------------------------------------------------------------------------------------
    -- Receive sequencer: latch (rx_latch_proc), classify and find the slot, apply (slot_proc /
    -- the EMCY FIFO) and report; an autostart reply is reported once tx_req_o shows a frame.
    -- Classification: RTR, SYNC and other function codes are unexpected; then a wrong DLC is
    -- malformed; then an error-control frame from a node in no slot is unexpected.
    -- ---------------------------------------------------------------------------------------------
    rx_seq_proc : process (clk_i, rst_n_i) is

        variable first_v : boolean;
        variable hit_v   : std_logic_vector(MAX_NODES - 1 downto 0);
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

                    hit_v   := (others => '0');
                    first_v := true;

                    for k in 0 to MAX_NODES - 1 loop

                        if first_v and cfg_node_i(7 * k + 6 downto 7 * k) /= node_none_c
                           and cfg_node_i(7 * k + 6 downto 7 * k) = node_of(rx_id_q) then
                            hit_v(k) := '1';
                            first_v  := false;
                        end if;

                    end loop;

                    class_v := RX_UNEXPECTED;
                    if rx_rtr_q = '0' and node_of(rx_id_q) /= node_none_c then
                        if func_code(rx_id_q) = FC_NMT_EC_C then
                            if rx_dlc_q /= ec_dlc_c then
                                class_v := RX_MALFORMED;
                            elsif not first_v then
                                class_v := RX_EC;
                            end if;
                        elsif func_code(rx_id_q) = FC_SYNC_EMCY_C then
                            if rx_dlc_q /= emcy_dlc_c then
                                class_v := RX_MALFORMED;
                            else
                                class_v := RX_EMCY;
                            end if;
                        end if;
                    end if;
                    rx_class <= class_v;
                    rx_hit   <= hit_v;
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

                    if tx_req = '1' or (pend_start_q and rx_hit) = (rx_hit'range => '0') then
                        rx_done_o  <= '1';
                        rx_reply_o <= '1';
                        rx_state   <= S_RX_IDLE;
                    end if;

            end case;

        end if;

    end process rx_seq_proc;

    -- what applying the error-control frame does: a boot-up with autostart requests NMT start,
    -- a guarding reply without an RTR out for it is unexpected (and ignored)
    rx_state_byte <= rx_data_q(6 downto 0);
    rx_toggle     <= rx_data_q(toggle_bit_c);
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
    -- Slots: per slot (static index k), in this order: host clear, frame taken by the FSM,
    -- received frame, ms tick, (re)load of the loss timer, configuration. A frame and a tick in
    -- the same cycle: the frame wins (the tick is not counted for that slot).
    -- Loss timer: remaining ms r = sub (heartbeat, fac = 0) or r = (fac - 1) * G + sub
    -- (guarding, fac = life time factor at a reload, sub wraps from 1 to G while fac > 1).
    -- A tick with r = 0 is the loss, so a reload with T (or G x factor) expires at the
    -- (T+1)-th tick after it.
    -- ---------------------------------------------------------------------------------------------
    slot_proc : process (clk_i, rst_n_i) is

        variable node_v   : node_id_t;
        variable mode_v   : std_logic_vector(1 downto 0);
        variable time_v   : unsigned(15 downto 0);
        variable life_v   : unsigned(7 downto 0);
        variable hb_v     : boolean; -- heartbeat consumer with T /= 0
        variable guard_v  : boolean; -- node guarding with G /= 0
        variable sup_v    : boolean; -- a loss can be detected
        variable heard_v  : boolean; -- the node was heard in this cycle
        variable reload_v : boolean; -- (re)start the loss timer
        variable sub_v    : unsigned(15 downto 0);
        variable fac_v    : unsigned(7 downto 0);
        variable gcnt_v   : unsigned(15 downto 0);
        variable armed_v  : std_logic;
        variable run_v    : std_logic;
        variable exp_v    : std_logic;
        variable out_v    : std_logic;

    begin

        if rst_n_i = '0' then
            cfg_node_q   <= (others => '0');
            cfg_mode_q   <= (others => '0');
            nmt_q        <= (others => (others => '0'));
            last_q       <= (others => (others => '0'));
            alive_q      <= (others => '0');
            lost_q       <= (others => '0');
            toggle_q     <= (others => '0');
            bootup_q     <= (others => '0');
            armed_q      <= (others => '0');
            sub_q        <= (others => (others => '0'));
            fac_q        <= (others => (others => '0'));
            grd_run_q    <= (others => '0');
            gcnt_q       <= (others => (others => '0'));
            exp_tog_q    <= (others => '0');
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
            cfg_node_q  <= cfg_node_i;
            cfg_mode_q  <= cfg_mode_i;

            for k in 0 to MAX_NODES - 1 loop

                node_v   := cfg_node_i(7 * k + 6 downto 7 * k);
                mode_v   := cfg_mode_i(2 * k + 1 downto 2 * k);
                time_v   := unsigned(cfg_time_i(16 * k + 15 downto 16 * k));
                life_v   := unsigned(cfg_life_i(8 * k + 7 downto 8 * k));
                hb_v     := node_v /= node_none_c and mode_v = mode_heartbeat_c and time_v /= 0;
                guard_v  := node_v /= node_none_c and mode_v = mode_guarding_c and time_v /= 0;
                sup_v    := hb_v or (guard_v and life_v /= 0);
                heard_v  := false;
                reload_v := false;
                sub_v    := sub_q(k);
                fac_v    := fac_q(k);
                gcnt_v   := gcnt_q(k);
                armed_v  := armed_q(k);
                run_v    := grd_run_q(k);
                exp_v    := exp_tog_q(k);
                out_v    := rtr_out_q(k);

                -- host clears the sticky bits (an event in the same cycle sets them again)
                if st_clear_i(k) = '1' then
                    lost_q(k)   <= '0';
                    toggle_q(k) <= '0';
                    bootup_q(k) <= '0';
                end if;

                -- the FSM took this slot's frame
                if tx_req = '1' and tx_ack_i = '1' and tx_slot = k then

                    case tx_kind is

                        when TX_RESET =>

                            pend_reset_q(k) <= '0';

                        when TX_START =>

                            pend_start_q(k) <= '0';

                        when TX_RTR =>

                            pend_rtr_q(k) <= '0';
                            out_v         := '1';

                    end case;

                end if;

                -- error-control frame from this slot's node
                if rx_apply = '1' and rx_hit(k) = '1' then
                    if rx_state_byte = NMT_ST_BOOTUP_C then
                        -- boot-up: record it, restart the toggle rule; heartbeat monitoring
                        -- restarts with the first heartbeat, guarding keeps polling
                        heard_v        := true;
                        bootup_q(k)    <= '1';
                        ev_bootup_o(k) <= '1';
                        nmt_q(k)       <= rx_state_byte;
                        last_q(k)      <= rx_time_q;
                        alive_q(k)     <= '1';
                        exp_v          := '0';
                        -- an RTR already taken for transmission stays outstanding: the booted
                        -- node answers it (toggle 0), and ignoring that reply would leave the
                        -- expectation one step behind
                        armed_v         := '0';
                        reload_v        := guard_v and run_v = '1';
                        pend_reset_q(k) <= '0';
                        if cfg_autostart_i(k) = '1' then
                            pend_start_q(k) <= '1';
                        end if;
                    elsif mode_v = mode_guarding_c then
                        -- guarding reply: only as the answer to an RTR that went out
                        if rtr_out_q(k) = '1' then
                            heard_v    := true;
                            out_v      := '0';
                            nmt_q(k)   <= rx_state_byte;
                            last_q(k)  <= rx_time_q;
                            alive_q(k) <= '1';
                            reload_v   := run_v = '1';
                            if rx_toggle /= exp_v then
                                toggle_q(k)    <= '1';
                                ev_toggle_o(k) <= '1';
                            end if;
                            -- alternate; after an error resynchronise to the received bit
                            exp_v := not rx_toggle;
                        end if;
                    else
                        -- heartbeat (or a slot without supervision: state only)
                        heard_v    := true;
                        nmt_q(k)   <= rx_state_byte;
                        last_q(k)  <= rx_time_q;
                        alive_q(k) <= '1';
                        reload_v   := hb_v;
                    end if;
                end if;

                -- ms tick: loss timer, then the guard period (RTR every G ticks from the first
                -- tick after guarding is enabled)
                if tick_ms_i = '1' then
                    if armed_v = '1' and not heard_v then
                        if sub_v = 0 then
                            armed_v      := '0';
                            alive_q(k)   <= '0';
                            lost_q(k)    <= '1';
                            ev_lost_o(k) <= '1';
                            if cfg_reset_on_loss_i(k) = '1' then
                                pend_reset_q(k) <= '1';
                            end if;
                        elsif sub_v = 1 and fac_v > 1 then
                            sub_v := time_v;
                            fac_v := fac_v - 1;
                        else
                            sub_v := sub_v - 1;
                        end if;
                    end if;
                    if guard_v then
                        if run_v = '0' or gcnt_v <= 1 then
                            gcnt_v        := time_v;
                            pend_rtr_q(k) <= '1';
                        else
                            gcnt_v := gcnt_v - 1;
                        end if;
                        -- first request: toggle expected 0, life timer started
                        if run_v = '0' then
                            run_v    := '1';
                            exp_v    := '0';
                            out_v    := '0';
                            reload_v := true;
                        end if;
                    end if;
                end if;

                if reload_v then
                    armed_v := '1';
                    sub_v   := time_v;
                    if guard_v then
                        fac_v := life_v;
                    else
                        fac_v := (others => '0');
                    end if;
                end if;

                -- supervision switched off, or the slot re-configured: restart it
                -- (gcnt is cleared too: besides being tidy, without it GHDL 2.0 --synth crashes
                -- with an internal error for MAX_NODES = 1)
                if not guard_v then
                    run_v  := '0';
                    gcnt_v := (others => '0');
                end if;
                if not sup_v then
                    armed_v := '0';
                end if;
                if node_v /= cfg_node_q(7 * k + 6 downto 7 * k)
                   or mode_v /= cfg_mode_q(2 * k + 1 downto 2 * k) then
                    armed_v         := '0';
                    run_v           := '0';
                    exp_v           := '0';
                    out_v           := '0';
                    alive_q(k)      <= '0';
                    pend_rtr_q(k)   <= '0';
                    pend_start_q(k) <= '0';
                    pend_reset_q(k) <= '0';
                end if;

                sub_q(k)     <= sub_v;
                fac_q(k)     <= fac_v;
                gcnt_q(k)    <= gcnt_v;
                armed_q(k)   <= armed_v;
                grd_run_q(k) <= run_v;
                exp_tog_q(k) <= exp_v;
                rtr_out_q(k) <= out_v;

            end loop;

        end if;

    end process slot_proc;

    -- ---------------------------------------------------------------------------------------------
    -- Transmit arbiter: the first slot with a pending request at or after rr_ptr (round robin);
    -- within a slot reset-node before start before RTR
    -- ---------------------------------------------------------------------------------------------
    pick_proc : process (pend_reset_q, pend_rtr_q, pend_start_q, rr_ptr) is

        variable any_v      : std_logic_vector(MAX_NODES - 1 downto 0);
        variable low_v      : slot_t; -- lowest pending slot
        variable low_rr_v   : slot_t; -- lowest pending slot at or above rr_ptr
        variable found_rr_v : boolean;
        variable slot_v     : slot_t;

    begin

        any_v      := pend_rtr_q or pend_start_q or pend_reset_q;
        low_v      := 0;
        low_rr_v   := 0;
        found_rr_v := false;

        for k in MAX_NODES - 1 downto 0 loop

            if any_v(k) = '1' then
                low_v := k;
                if k >= rr_ptr then
                    low_rr_v   := k;
                    found_rr_v := true;
                end if;
            end if;

        end loop;

        if found_rr_v then
            slot_v := low_rr_v;
        else
            slot_v := low_v;
        end if;

        pick_slot  <= slot_v;
        pick_valid <= '0';
        pick_kind  <= TX_RTR;

        for k in 0 to MAX_NODES - 1 loop

            if k = slot_v then
                pick_valid <= any_v(k);
                if pend_reset_q(k) = '1' then
                    pick_kind <= TX_RESET;
                elsif pend_start_q(k) = '1' then
                    pick_kind <= TX_START;
                end if;
            end if;

        end loop;

    end process pick_proc;

    tx_arb_proc : process (clk_i, rst_n_i) is
    begin

        if rst_n_i = '0' then
            tx_req  <= '0';
            tx_slot <= 0;
            tx_kind <= TX_RTR;
            rr_ptr  <= 0;
        elsif rising_edge(clk_i) then
            if tx_req = '1' then
                if tx_ack_i = '1' then
                    tx_req <= '0';
                    rr_ptr <= next_slot(tx_slot);
                end if;
            elsif pick_valid = '1' then
                tx_req  <= '1';
                tx_slot <= pick_slot;
                tx_kind <= pick_kind;
            end if;
        end if;

    end process tx_arb_proc;

    -- frame of the request being presented (datapath, qualified by tx_req)
    tx_frame_proc : process (clk_i) is

        variable node_v : node_id_t;

    begin

        if rising_edge(clk_i) then
            if tx_req = '0' and pick_valid = '1' then
                node_v := node_none_c;

                for k in 0 to MAX_NODES - 1 loop

                    if k = pick_slot then
                        node_v := cfg_node_i(7 * k + 6 downto 7 * k);
                    end if;

                end loop;

                tx_data_o <= (others => '0');

                case pick_kind is

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

    tx_req_o <= tx_req;

    -- ---------------------------------------------------------------------------------------------
    -- EMCY FIFO. The RAM is read every cycle at the address of the next head, so emcy_q holds
    -- the head one cycle after it was written; an entry is counted for the host (emcy_count)
    -- one cycle after its write, when emcy_q can show it. A push into a full FIFO is dropped
    -- and sets emcy_lost (a pop in the same cycle makes room).
    -- ---------------------------------------------------------------------------------------------
    emcy_pop  <= '1' when emcy_pop_i = '1' and emcy_count /= 0 else '0';
    emcy_push <= '1' when rx_state = S_RX_APPLY and rx_class = RX_EMCY
                          and (emcy_fill < EMCY_DEPTH or emcy_pop = '1') else
                 '0';

    -- entries stored, including the one written in the previous cycle
    emcy_fill <= emcy_count + 1 when emcy_push_d = '1' else
                 emcy_count;

    emcy_rd_nxt <= next_ptr(emcy_rd) when emcy_pop = '1' else
                   emcy_rd;

    emcy_ctrl_proc : process (clk_i, rst_n_i) is
    begin

        if rst_n_i = '0' then
            emcy_wr     <= 0;
            emcy_rd     <= 0;
            emcy_count  <= 0;
            emcy_push_d <= '0';
            emcy_lost   <= '0';
            ev_emcy_o   <= '0';
        elsif rising_edge(clk_i) then
            if emcy_push = '1' then
                emcy_wr <= next_ptr(emcy_wr);
            end if;
            emcy_rd     <= emcy_rd_nxt;
            emcy_push_d <= emcy_push;
            -- the event coincides with the entry becoming visible in emcy_count
            ev_emcy_o <= emcy_push_d;
            if emcy_push_d = '1' and emcy_pop = '0' then
                emcy_count <= emcy_count + 1;
            elsif emcy_push_d = '0' and emcy_pop = '1' then
                emcy_count <= emcy_count - 1;
            end if;
            if emcy_clear_i = '1' then
                emcy_lost <= '0';
            end if;
            if rx_state = S_RX_APPLY and rx_class = RX_EMCY and emcy_push = '0' then
                emcy_lost <= '1';
            end if;
        end if;

    end process emcy_ctrl_proc;

    -- simple dual-port RAM, synchronous read, no reset (inferred as block RAM)
    emcy_ram_proc : process (clk_i) is
    begin

        if rising_edge(clk_i) then
            if emcy_push = '1' then
                emcy_mem(emcy_wr) <= node_of(rx_id_q) & rx_data_q & rx_time_q;
            end if;
            emcy_q <= emcy_mem(emcy_rd_nxt);
        end if;

    end process emcy_ram_proc;

    emcy_count_o <= std_logic_vector(to_unsigned(emcy_count, 7));
    emcy_lost_o  <= emcy_lost;
    emcy_node_o  <= emcy_q(emcy_w_c - 1 downto emcy_w_c - 7);
    emcy_data_o  <= emcy_q(95 downto 32);
    emcy_time_o  <= emcy_q(31 downto 0);

    -- ---------------------------------------------------------------------------------------------
    -- Flattened per-slot status
    -- ---------------------------------------------------------------------------------------------

    status_gen : for k in 0 to MAX_NODES - 1 generate
        st_nmt_o(7 * k + 6 downto 7 * k)     <= nmt_q(k);
        st_last_o(32 * k + 31 downto 32 * k) <= last_q(k);
    end generate status_gen;

    st_alive_o  <= alive_q;
    st_lost_o   <= lost_q;
    st_toggle_o <= toggle_q;
    st_bootup_o <= bootup_q;

end architecture rtl;
