-- =================================================================================================
-- Title    : canopen_fault_supervisor
-- Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
-- SPDX-License-Identifier: Apache-2.0
-- =================================================================================================
-- Module:
--   The fault side of the master's datapath (part of canopen_master_core): the error latch the
--   FSM reads in St1 and St13, the state watchdog, the controller re-initialisation of St0 and
--   the CAN status snapshot for the host.
-- Purpose:
--   * Error latch (cleared in St13): CAN errors (ERRIF, RX overflow, TXERR, a fire of an
--     unloaded buffer), bus-off still present after busoff_us_c, a host re-init request, a
--     chip reset found by the controller, a node event (heartbeat loss, guarding toggle).
--   * State watchdog: watchdog_o after WATCHDOG_US us in one FSM state (bounded waits, G4).
--   * St0: a RESET of the controller on entry from St13 (G1, not after a chip reset the
--     controller handles itself), and after a failed initialisation every REINIT_BACKOFF_MS;
--     init_done_o is masked until the controller has dropped the previous init_done.
--   * TEC / REC / EFLG registered for the host; ev_init_o on a rising init_done or init_fail.
--   Decisions: docs/canopen_master_top.md (error handling), docs/fsm.md (St0, St13).
-- =================================================================================================

library ieee;
    use ieee.std_logic_1164.all;
    use ieee.numeric_std.all;

library work;
    use work.mcp2510_pkg.all;

entity canopen_fault_supervisor is
    generic (
        CAN_BITRATE_BPS   : positive := 1_000_000; -- CAN bit rate (bus-off recovery bound)
        WATCHDOG_US       : positive := 20_000;    -- longest wait in one state
        REINIT_BACKOFF_MS : positive := 100        -- between init attempts
    );
    port (
        -- clock and reset
        clk_i     : in    std_logic; -- system clock
        rst_n_i   : in    std_logic; -- async reset, active low (synced)
        tick_us_i : in    std_logic; -- 1-cycle strobe every us
        -- mcp2510_ctrl status
        init_done_i   : in    std_logic;                    -- chip in normal mode
        init_fail_i   : in    std_logic;                    -- initialisation failed
        chip_lost_i   : in    std_logic;                    -- strobe: chip reset found
        tec_i         : in    std_logic_vector(7 downto 0); -- live TEC
        rec_i         : in    std_logic_vector(7 downto 0); -- live REC
        eflg_i        : in    std_logic_vector(7 downto 0); -- live EFLG
        int_errif_i   : in    std_logic;                    -- strobe: INT handled with ERRIF
        rx_overflow_i : in    std_logic;                    -- strobe: a received frame lost
        tx_fault_i    : in    std_logic;                    -- strobe: TXERR or an unloaded fire
        -- other sources
        host_reinit_i : in    std_logic; -- strobe: CTRL.REINIT
        node_error_i  : in    std_logic; -- strobe: heartbeat loss or guarding toggle
        -- the FSM
        state_change_i : in    std_logic; -- strobe: the FSM changes state
        in_init_i      : in    std_logic; -- in St0
        in_error_i     : in    std_logic; -- in St13: the latch is cleared
        -- results
        err_can_o    : out   std_logic;                    -- latched: CAN error
        err_busoff_o : out   std_logic;                    -- latched: bus-off not recovered in time
        err_reinit_o : out   std_logic;                    -- latched: host re-init request
        err_node_o   : out   std_logic;                    -- latched: node event
        err_chip_o   : out   std_logic;                    -- latched: chip reset found
        watchdog_o   : out   std_logic;                    -- WATCHDOG_US in the current state
        reinit_o     : out   std_logic;                    -- pulse: re-initialise the controller
        init_done_o  : out   std_logic;                    -- init_done_i as the FSM sees it (St0)
        tec_o        : out   std_logic_vector(7 downto 0); -- registered TEC
        rec_o        : out   std_logic_vector(7 downto 0); -- registered REC
        eflg_o       : out   std_logic_vector(7 downto 0); -- registered EFLG
        ev_init_o    : out   std_logic                     -- strobe: init done or failed
    );
end entity canopen_fault_supervisor;

architecture rtl of canopen_fault_supervisor is

    constant backoff_us_c : positive := 1000 * REINIT_BACKOFF_MS;
    -- bus-off: the MCP2510 returns to error-active by itself after 128 x 11 recessive bits;
    -- on a loaded bus one such sequence ends each frame, so 128 longest frames (160 bits)
    -- bound it. Only a chip still bus-off after that is re-initialised (G1).
    constant busoff_us_c : positive := (128 * 160 * 1000 + CAN_BITRATE_BPS / 1000 - 1)
                                       / (CAN_BITRATE_BPS / 1000);
    -- error latch
    signal err_can    : std_logic;
    signal err_busoff : std_logic;
    signal err_reinit : std_logic;
    signal err_node   : std_logic;
    -- the controller found the chip reset behind its back (CANSTAT.OPMOD not normal) and
    -- re-initialises it by itself: St13 reports it, St0 (G1) waits for init_done without
    -- asking for another RESET (chip_reinit, until St0 is entered)
    signal err_chip    : std_logic;
    signal chip_reinit : std_logic;
    -- state watchdog and St0 re-initialisation
    signal wd_us        : natural range 0 to WATCHDOG_US;
    signal backoff_us   : natural range 0 to backoff_us_c;
    signal busoff_us    : natural range 0 to busoff_us_c;
    signal reinit_pulse : std_logic;
    -- a re-initialisation was requested and the controller has not restarted yet: St0 must
    -- not leave on the init_done of the previous initialisation
    signal reinit_wait : std_logic;
    -- CAN status snapshot for the host; init_done / init_fail one cycle late (edges)
    signal can_tec     : std_logic_vector(7 downto 0);
    signal can_rec     : std_logic_vector(7 downto 0);
    signal can_eflg    : std_logic_vector(7 downto 0);
    signal init_done_q : std_logic;
    signal init_fail_q : std_logic;

begin

    fault_proc : process (clk_i, rst_n_i) is
    begin

        if rst_n_i = '0' then
            err_can      <= '0';
            err_busoff   <= '0';
            err_reinit   <= '0';
            err_node     <= '0';
            err_chip     <= '0';
            chip_reinit  <= '0';
            wd_us        <= 0;
            backoff_us   <= 0;
            busoff_us    <= 0;
            reinit_pulse <= '0';
            reinit_wait  <= '0';
            init_done_q  <= '0';
            init_fail_q  <= '0';
            can_tec      <= (others => '0');
            can_rec      <= (others => '0');
            can_eflg     <= (others => '0');
        elsif rising_edge(clk_i) then
            reinit_pulse <= '0';
            init_done_q  <= init_done_i;
            init_fail_q  <= init_fail_i;

            -- error latch --------------------------------------------------------------------
            if int_errif_i = '1' or rx_overflow_i = '1' or tx_fault_i = '1' then
                err_can <= '1';
            end if;
            -- bus-off (EFLG.TXBO, shown in STATUS.BUS_OFF): wait for the chip's own recovery;
            -- still bus-off after busoff_us_c -> re-initialise (St13 -> St0, G1), once
            if can_eflg(MCP_EFLG_TXBO_BIT_C) = '0' or init_done_i = '0' then
                busoff_us <= 0;
            elsif tick_us_i = '1' and busoff_us = busoff_us_c - 1 then
                busoff_us  <= busoff_us_c;
                err_busoff <= '1';
            elsif tick_us_i = '1' and busoff_us < busoff_us_c then
                busoff_us <= busoff_us + 1;
            end if;
            if host_reinit_i = '1' then
                err_reinit <= '1';
            end if;
            if chip_lost_i = '1' then
                err_chip    <= '1';
                chip_reinit <= '1';
            end if;
            if node_error_i = '1' then
                err_node <= '1';
            end if;
            if in_error_i = '1' then
                err_can    <= '0';
                err_busoff <= '0';
                err_reinit <= '0';
                err_node   <= '0';
                err_chip   <= '0';
            end if;

            -- state watchdog: bounded waits (G4) ----------------------------------------------
            if state_change_i = '1' then
                wd_us <= 0;
            elsif tick_us_i = '1' and wd_us < WATCHDOG_US then
                wd_us <= wd_us + 1;
            end if;

            -- St0: re-initialise the controller on entry from St13 (G1), and after a failed
            -- initialisation once the back-off time has passed (T1) -------------------------
            if in_init_i = '1' and state_change_i = '1' and init_done_q = '1'
               and chip_reinit = '0' then
                reinit_pulse <= '1';
                reinit_wait  <= '1';
            end if;
            if in_init_i = '1' and state_change_i = '1' then
                chip_reinit <= '0';
            end if;
            if reinit_wait = '1' and reinit_pulse = '0' and init_done_i = '0' then
                reinit_wait <= '0';
            end if;
            if in_init_i = '1' and init_fail_i = '1' then
                if backoff_us = backoff_us_c then
                    backoff_us   <= 0;
                    reinit_pulse <= '1';
                elsif tick_us_i = '1' then
                    backoff_us <= backoff_us + 1;
                end if;
            else
                backoff_us <= 0;
            end if;

            -- TEC/REC/EFLG for the host: mcp2510_ctrl polls them every ERR_POLL_US and after
            -- every error interrupt, and clears them with the chip's RESET ------------------
            can_tec  <= tec_i;
            can_rec  <= rec_i;
            can_eflg <= eflg_i;
        end if;

    end process fault_proc;

    watchdog_o <= '1' when wd_us = WATCHDOG_US else
                  '0';

    -- masked from the entry into St0 (G1) until the controller has dropped init_done
    init_done_o <= init_done_i and not reinit_wait and not reinit_pulse
                   and not (in_init_i and state_change_i);

    reinit_o     <= reinit_pulse;
    err_can_o    <= err_can;
    err_busoff_o <= err_busoff;
    err_reinit_o <= err_reinit;
    err_node_o   <= err_node;
    err_chip_o   <= err_chip;
    tec_o        <= can_tec;
    rec_o        <= can_rec;
    eflg_o       <= can_eflg;
    ev_init_o    <= (init_done_i and not init_done_q) or (init_fail_i and not init_fail_q);

end architecture rtl;
