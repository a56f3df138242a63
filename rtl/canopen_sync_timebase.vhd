-- =================================================================================================
-- Title    : canopen_sync_timebase
-- Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
-- SPDX-License-Identifier: Apache-2.0
-- =================================================================================================
-- Module:
--   The time base and the SYNC producer of canopen_master_core (a datapath block next to the
--   14-state FSM; the FSM itself only sees sync_loaded / sync_fire through the core's
--   conditions).
-- Purpose:
--   * Time base: 1 us and 1 ms strobes (one clock cycle each) from a divider of the system
--     clock, and free-running 32-bit us and ms counters (EMCY and heartbeat time stamps).
--   * SYNC producer, exact period in clock cycles: a us timer counts SYNC_PERIOD_US; at its
--     end the SYNC preloaded in TXB2 is fired (sync_fire_o: one cycle, the TX2RTS request of
--     mcp2510_ctrl). A period that ends with nothing preloaded (sync_loaded_o = 0) is "late":
--     the fire follows as soon as the preload is done. The fire clears sync_loaded_o; the FSM
--     preloads the next SYNC (St2, St12) and load_done_i sets it again.
--   * SYNC counter (CiA 301 1019h, SYNC_OVERFLOW >= 2): the counter byte of the SYNC being
--     preloaded (sync_counter_o, 1 .. overflow), what the PDOs of a cycle belong to
--     (sync_sent_o: that counter byte, or without counter the number of SYNCs sent modulo
--     256), and the number of SYNCs fired (sync_count_o). A change of SYNC_OVERFLOW restarts
--     the counter at 1 and invalidates the preloaded SYNC (also one being loaded: stale until
--     the next encapsulation of a SYNC, encap_sync_i).
--   * Synchronous window (1007h): open from each fire for SYNC_WINDOW_US, 0 = always open.
--   * A re-initialisation of the chip (init_done_i = 0) leaves TXB2 undefined: nothing is
--     fired until the SYNC is preloaded again.
--   Order of the updates of one edge (the last one wins): preload done, chip not initialised,
--   fire, SYNC_OVERFLOW change. docs/canopen_master_top.md (SYNC producer) for the timing.
--   The 32-bit counters count in two 16-bit halves (inc_split: the upper half steps on a
--   registered "lower half all ones" flag) and the 32-bit compares are split the same way
--   (lt_split): no path through all 32 bits. The period timer is kept as its next value only,
--   sync_next = (us into the period) + 1 (1 at the period start): the period end compares it with
--   the period, and sync_next_o gives it to the core (the position in the period is
--   sync_next_o - 1; the core's half-period compare is written for sync_next_o).
-- =================================================================================================

library ieee;
    use ieee.std_logic_1164.all;
    use ieee.numeric_std.all;

library work;
    use work.canopen_util_pkg.all;

entity canopen_sync_timebase is
    generic (
        CLK_FREQ_HZ : positive := 20_000_000 -- clk_i frequency [Hz], whole MHz
    );
    port (
        -- clock and reset
        clk_i   : in    std_logic; -- system clock
        rst_n_i : in    std_logic; -- async reset, active low (synced)
        -- time base
        tick_us_o : out   std_logic;                     -- 1-cycle strobe every us
        tick_ms_o : out   std_logic;                     -- 1-cycle strobe every ms
        time_us_o : out   std_logic_vector(31 downto 0); -- us since reset
        time_ms_o : out   std_logic_vector(31 downto 0); -- ms since reset
        -- SYNC configuration (host registers)
        sync_en_i        : in    std_logic;                     -- CTRL.SYNC_EN
        sync_period_us_i : in    std_logic_vector(31 downto 0); -- SYNC_PERIOD_US, 0 = off
        sync_overflow_i  : in    std_logic_vector(7 downto 0);  -- SYNC_OVERFLOW (1019h)
        sync_window_us_i : in    std_logic_vector(31 downto 0); -- SYNC_WINDOW_US, 0 = always
        -- preload of TXB2 and the chip
        load_done_i  : in    std_logic; -- strobe: the SYNC is in TXB2 (St12, controller loaded)
        encap_sync_i : in    std_logic; -- strobe: a SYNC frame is being built (St2)
        init_done_i  : in    std_logic; -- the controller has initialised the chip
        -- SYNC producer state
        sync_loaded_o  : out   std_logic;                     -- TXB2 holds a valid SYNC
        sync_fire_o    : out   std_logic;                     -- strobe: fire TXB2 (TX2RTS)
        sync_fire_q_o  : out   std_logic;                     -- sync_fire_o one cycle later
        sync_counter_o : out   std_logic_vector(7 downto 0);  -- counter byte to preload
        sync_sent_o    : out   std_logic_vector(7 downto 0);  -- SYNC the PDOs belong to
        sync_count_o   : out   std_logic_vector(31 downto 0); -- SYNCs fired since reset
        sync_next_o    : out   std_logic_vector(31 downto 0); -- us into the period + 1
        window_open_o  : out   std_logic                      -- synchronous window open
    );
end entity canopen_sync_timebase;

architecture rtl of canopen_sync_timebase is

    constant cycles_per_us_c : positive := (CLK_FREQ_HZ + 999_999) / 1_000_000;

    -- time base
    signal us_div  : natural range 0 to cycles_per_us_c - 1;
    signal ms_div  : natural range 0 to 999;
    signal tick_us : std_logic;
    signal tick_ms : std_logic;
    signal time_us : unsigned(31 downto 0);
    signal time_ms : unsigned(31 downto 0);
    -- inc_split flags of the counters: the lower half is all ones
    signal time_us_lo1 : std_logic;
    signal time_ms_lo1 : std_logic;
    -- SYNC producer; sync_next = (us into the period) + 1
    signal sync_next    : unsigned(31 downto 0);
    signal sync_nx_lo1  : std_logic;
    signal sync_cnt_lo1 : std_logic;
    signal sync_loaded  : std_logic;
    signal sync_late    : std_logic;
    signal sync_counter : unsigned(7 downto 0);
    signal sync_count   : unsigned(31 downto 0);
    signal sync_sent    : unsigned(7 downto 0);
    signal sync_fire    : std_logic;
    signal sync_fire_q  : std_logic;
    -- SYNC_OVERFLOW as the last cycle saw it; the preloaded SYNC is stale after a change
    signal sync_ovf_q   : std_logic_vector(7 downto 0);
    signal sync_ovf_chg : std_logic;
    signal sync_stale   : std_logic;
    -- synchronous window: us since the last fire (saturating)
    signal window_us  : unsigned(31 downto 0);
    signal window_lo1 : std_logic;

begin

    -- ---------------------------------------------------------------------------------------------
    -- Time base: 1 us and 1 ms strobes, free-running counters
    -- ---------------------------------------------------------------------------------------------
    timebase_proc : process (clk_i, rst_n_i) is
    begin

        if rst_n_i = '0' then
            us_div      <= 0;
            ms_div      <= 0;
            tick_us     <= '0';
            tick_ms     <= '0';
            time_us     <= (others => '0');
            time_ms     <= (others => '0');
            time_us_lo1 <= '0';
            time_ms_lo1 <= '0';
        elsif rising_edge(clk_i) then
            tick_us <= '0';
            tick_ms <= '0';
            if us_div = cycles_per_us_c - 1 then
                us_div      <= 0;
                tick_us     <= '1';
                time_us     <= inc_split(time_us, time_us_lo1);
                time_us_lo1 <= lo_ones_after_inc(time_us);
                if ms_div = 999 then
                    ms_div      <= 0;
                    tick_ms     <= '1';
                    time_ms     <= inc_split(time_ms, time_ms_lo1);
                    time_ms_lo1 <= lo_ones_after_inc(time_ms);
                else
                    ms_div <= ms_div + 1;
                end if;
            else
                us_div <= us_div + 1;
            end if;
        end if;

    end process timebase_proc;

    -- ---------------------------------------------------------------------------------------------
    -- SYNC producer
    -- ---------------------------------------------------------------------------------------------
    sync_ovf_chg <= '1' when sync_overflow_i /= sync_ovf_q else
                    '0';

    sync_proc : process (clk_i, rst_n_i) is
    begin

        if rst_n_i = '0' then
            sync_next    <= to_unsigned(1, 32);
            sync_nx_lo1  <= '0';
            sync_cnt_lo1 <= '0';
            sync_loaded  <= '0';
            sync_late    <= '0';
            sync_counter <= to_unsigned(1, 8);
            sync_count   <= (others => '0');
            sync_sent    <= (others => '0');
            sync_fire    <= '0';
            sync_fire_q  <= '0';
            sync_ovf_q   <= (others => '0');
            sync_stale   <= '0';
            window_us    <= (others => '0');
            window_lo1   <= '0';
        elsif rising_edge(clk_i) then
            sync_fire   <= '0';
            sync_fire_q <= sync_fire;

            -- TXB2 loaded with the SYNC (a stale one does not count)
            if load_done_i = '1' then
                sync_loaded <= not sync_stale;
            end if;
            -- a RESET of the chip (any re-initialisation: bus-off, INIT retry, CTRL.REINIT)
            -- leaves TXB2 undefined: nothing is fired until St2/St12 have loaded it again
            if init_done_i = '0' then
                sync_loaded <= '0';
            end if;

            -- exact period in clock cycles, started by the TX2RTS pin
            -- (us into the period + 1 >= period, i.e. not sync_next < period)
            if sync_en_i = '0' or unsigned(sync_period_us_i) = 0 then
                sync_next   <= to_unsigned(1, 32);
                sync_nx_lo1 <= '0';
                sync_late   <= '0';
            elsif tick_us = '1' then
                if not lt_split(sync_next, unsigned(sync_period_us_i)) then
                    sync_next   <= to_unsigned(1, 32);
                    sync_nx_lo1 <= '0';
                    if sync_loaded = '1' then
                        sync_fire <= '1';
                    else
                        sync_late <= '1';
                    end if;
                else
                    sync_next   <= inc_split(sync_next, sync_nx_lo1);
                    sync_nx_lo1 <= lo_ones_after_inc(sync_next);
                end if;
            end if;
            if sync_late = '1' and sync_loaded = '1' and sync_fire = '0' then
                sync_late <= '0';
                sync_fire <= '1';
            end if;
            -- (saturates: all ones is the upper half all ones with the lower half's flag)
            if sync_fire = '1' then
                window_us  <= (others => '0');
                window_lo1 <= '0';
            elsif tick_us = '1'
                  and not (window_lo1 = '1' and window_us(31 downto 16) = x"FFFF") then
                window_us  <= inc_split(window_us, window_lo1);
                window_lo1 <= lo_ones_after_inc(window_us);
            end if;
            if sync_fire = '1' then
                sync_loaded  <= '0';
                sync_count   <= inc_split(sync_count, sync_cnt_lo1);
                sync_cnt_lo1 <= lo_ones_after_inc(sync_count);
                -- what the PDOs of this cycle belong to: the counter byte of the SYNC just sent,
                -- or (SYNC without counter byte) the number of SYNCs sent, modulo 256
                if unsigned(sync_overflow_i) >= 2 then
                    sync_sent <= sync_counter;
                else
                    sync_sent <= sync_count(7 downto 0) + 1;
                end if;
                if unsigned(sync_overflow_i) >= 2
                   and sync_counter >= unsigned(sync_overflow_i) then
                    sync_counter <= to_unsigned(1, 8);
                elsif unsigned(sync_overflow_i) >= 2 then
                    sync_counter <= sync_counter + 1;
                end if;
            end if;

            -- SYNC_OVERFLOW changed (CiA 301 1019h): the counter restarts at 1 and the SYNC
            -- preloaded in TXB2 (or being loaded) is built again, so the next SYNC sent uses
            -- the new value; a SYNC already started (TX2RTS fired) is not affected
            sync_ovf_q <= sync_overflow_i;
            if encap_sync_i = '1' then
                sync_stale <= '0';
            end if;
            if sync_ovf_chg = '1' then
                sync_counter <= to_unsigned(1, 8);
                sync_loaded  <= '0';
                sync_stale   <= '1';
            end if;
        end if;

    end process sync_proc;

    window_open_o <= '1' when unsigned(sync_window_us_i) = 0 else
                     '1' when lt_split(window_us, unsigned(sync_window_us_i)) else
                     '0';

    tick_us_o      <= tick_us;
    tick_ms_o      <= tick_ms;
    time_us_o      <= std_logic_vector(time_us);
    time_ms_o      <= std_logic_vector(time_ms);
    sync_loaded_o  <= sync_loaded;
    sync_fire_o    <= sync_fire;
    sync_fire_q_o  <= sync_fire_q;
    sync_counter_o <= std_logic_vector(sync_counter);
    sync_sent_o    <= std_logic_vector(sync_sent);
    sync_count_o   <= std_logic_vector(sync_count);
    sync_next_o    <= std_logic_vector(sync_next);

end architecture rtl;
