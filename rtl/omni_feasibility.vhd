-- =================================================================================================
-- Title    : omni_feasibility
-- Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
-- SPDX-License-Identifier: Apache-2.0
-- =================================================================================================
-- Module:
--   Feasibility check of the Omni-ID cycle (part of omni_engine): does the worst case of one
--   cycle fit in the cycle period?
-- Purpose:
--   * bits = wc(broadcast DLC) [+ wc(0) for the Omni SYNC with SYNC_MODE 1] + the sum of
--     wc(slot DLC) over the valid node-table slots; wc(n) = worst-case bits of a standard data
--     frame with n data bytes, stuff bits and intermission included (DLC 9..15 count as 8).
--   * feasible_o = bits * (10**9 / BITRATE_BPS) <= period_us * 1000 and not cfg_err_i. Both
--     constants are divided by their greatest common divisor at elaboration (1 and 1 at
--     1 Mbit/s), so the usual bit rates need no multiplier.
--   * Pipelined, no divider: the sum is serial (one term per clock, the term registered before
--     the add, N_SLOTS + 2 terms), then two registered products and a compare in two stages
--     (four 12-bit chunks, less / equal registered, then combined). bits_o and feasible_o
--     follow a change of the inputs within 2 * N_SLOTS + 10 cycles; feasible_o is 0 for the
--     first cycles after reset.
--   Decisions and the reference model: docs/omni_engine.md (Feasibility).
-- =================================================================================================

library ieee;
    use ieee.std_logic_1164.all;
    use ieee.numeric_std.all;

entity omni_feasibility is
    generic (
        N_SLOTS     : positive range 1 to 8 := 8;        -- node-table slots
        BITRATE_BPS : positive              := 1_000_000 -- CAN bit rate
    );
    port (
        -- clock and reset
        clk_i   : in    std_logic; -- system clock
        rst_n_i : in    std_logic; -- async reset, active low (synced)
        -- the cycle
        bc_dlc_i     : in    std_logic_vector(3 downto 0);               -- broadcast DLC
        sync_mode_i  : in    std_logic;                                  -- Omni SYNC in the cycle
        slot_valid_i : in    std_logic_vector(N_SLOTS - 1 downto 0);     -- slot k expects feedback
        slot_dlc_i   : in    std_logic_vector(4 * N_SLOTS - 1 downto 0); -- its DLC, 4k+3..4k
        period_us_i  : in    std_logic_vector(31 downto 0);              -- cycle period [us]
        cfg_err_i    : in    std_logic;                                  -- layout out of range
        -- result
        bits_o     : out   std_logic_vector(15 downto 0); -- worst-case bits of one cycle
        feasible_o : out   std_logic                      -- '1': the cycle fits the period
    );
end entity omni_feasibility;

architecture rtl of omni_feasibility is

    constant ns_per_s_c   : natural := 1_000_000_000;
    constant ns_per_us_c  : natural := 1000;
    constant ns_per_bit_c : natural := ns_per_s_c / BITRATE_BPS;

    type nat_arr_t is array (natural range <>) of natural;

    -- worst-case bits of a standard data frame with n data bytes, intermission included:
    -- 44 + 8n + floor((34 + 8n - 1) / 4) + 3

    function wc_table return nat_arr_t is

        variable t : nat_arr_t(0 to 8);

    begin

        for n in 0 to 8 loop

            t(n) := 44 + 8 * n + (34 + 8 * n - 1) / 4 + 3;

        end loop;

        return t;

    end function wc_table;

    constant wc_bits_c : nat_arr_t(0 to 8) := wc_table;

    -- greatest common divisor (elaboration only)

    function gcd (a : positive; b : positive) return positive is

        variable x : natural;
        variable y : natural;
        variable t : natural;

    begin

        x := a;
        y := b;

        while y /= 0 loop

            t := x mod y;
            x := y;
            y := t;

        end loop;

        return x;

    end function gcd;

    -- bits * ns_per_bit <= period_us * 1000, both sides divided by their gcd (the same
    -- inequality with small constants: 1 and 1 at 1 Mbit/s, 8 and 1 at 125 kbit/s)
    constant feas_g_c : positive := gcd(ns_per_bit_c, ns_per_us_c);
    constant feas_a_c : positive := ns_per_bit_c / feas_g_c;
    constant feas_b_c : positive := ns_per_us_c / feas_g_c;

    function check_config return boolean is
    begin

        assert ns_per_s_c mod BITRATE_BPS = 0
            report "omni_feasibility: BITRATE_BPS must divide 10**9 (whole ns per bit)"
            severity failure;
        assert false
            report "omni_feasibility: " & integer'image(ns_per_bit_c) & " ns per bit, frames "
                   & integer'image(wc_bits_c(0)) & " .. " & integer'image(wc_bits_c(8))
                   & " bits worst case, bits * " & integer'image(feas_a_c) & " <= period_us * "
                   & integer'image(feas_b_c)
            severity note;
        return true;

    end function check_config;

    constant config_ok_c : boolean := check_config;

    -- worst-case bits of a frame with DLC d (9..15 count as 8)

    function wc_of (d : std_logic_vector(3 downto 0)) return natural is
    begin

        if d(3) = '1' then
            return wc_bits_c(8);
        end if;

        return wc_bits_c(to_integer(unsigned(d(2 downto 0))));

    end function wc_of;

    -- term index (0 broadcast, 1 SYNC, 2 + k slot k), the registered term, last-term flag
    signal f_idx  : natural range 0 to N_SLOTS + 1;
    signal f_term : natural range 0 to 255;
    signal f_last : std_logic;
    -- running sum, the sum of the last complete pass
    signal f_acc  : unsigned(15 downto 0);
    signal f_bits : unsigned(15 downto 0);
    -- the two sides of the inequality
    signal f_prod_a : unsigned(47 downto 0);
    signal f_prod_b : unsigned(47 downto 0);
    -- per 12-bit chunk of the products: a < b, a = b
    signal f_lt     : std_logic_vector(3 downto 0);
    signal f_eq     : std_logic_vector(3 downto 0);
    signal feasible : std_logic;

begin

    feas_proc : process (clk_i, rst_n_i) is

        variable term_v : natural range 0 to 255;
        variable le_v   : std_logic;

    begin

        if rst_n_i = '0' then
            f_idx    <= 0;
            f_term   <= 0;
            f_last   <= '0';
            f_acc    <= (others => '0');
            f_bits   <= (others => '0');
            f_prod_a <= (others => '1');
            f_prod_b <= (others => '0');
            f_lt     <= (others => '0');
            f_eq     <= (others => '0');
            feasible <= '0';
        elsif rising_edge(clk_i) then
            term_v := 0;

            if f_idx = 0 then
                term_v := wc_of(bc_dlc_i);
            elsif f_idx = 1 then
                if sync_mode_i = '1' then
                    term_v := wc_bits_c(0);
                end if;
            else

                for k in 0 to N_SLOTS - 1 loop

                    if f_idx = k + 2 and slot_valid_i(k) = '1' then
                        term_v := wc_of(slot_dlc_i(4 * k + 3 downto 4 * k));
                    end if;

                end loop;

            end if;

            -- the term is registered (with the last-term flag) and added one cycle later
            f_term <= term_v;
            if f_idx = N_SLOTS + 1 then
                f_last <= '1';
                f_idx  <= 0;
            else
                f_last <= '0';
                f_idx  <= f_idx + 1;
            end if;

            if f_last = '1' then
                f_bits <= f_acc + f_term;
                f_acc  <= (others => '0');
            else
                f_acc <= f_acc + f_term;
            end if;

            f_prod_a <= resize(f_bits * to_unsigned(feas_a_c, 32), 48);
            f_prod_b <= resize(unsigned(period_us_i) * to_unsigned(feas_b_c, 16), 48);

            -- compare in two stages: four 12-bit chunks (less than / equal) registered, then
            -- combined from the top chunk down
            for c in 0 to 3 loop

                if f_prod_a(12 * c + 11 downto 12 * c) < f_prod_b(12 * c + 11 downto 12 * c) then
                    f_lt(c) <= '1';
                else
                    f_lt(c) <= '0';
                end if;
                if f_prod_a(12 * c + 11 downto 12 * c) = f_prod_b(12 * c + 11 downto 12 * c) then
                    f_eq(c) <= '1';
                else
                    f_eq(c) <= '0';
                end if;

            end loop;

            -- a <= b: from the lowest chunk up, a chunk less, or equal and the lower ones <=
            le_v := f_lt(0) or f_eq(0);

            for c in 1 to 3 loop

                le_v := f_lt(c) or (f_eq(c) and le_v);

            end loop;

            if le_v = '1' and cfg_err_i = '0' then
                feasible <= '1';
            else
                feasible <= '0';
            end if;
        end if;

    end process feas_proc;

    bits_o     <= std_logic_vector(f_bits);
    feasible_o <= feasible;

end architecture rtl;
