-- =================================================================================================
-- Title    : canopen_counter_bank
-- Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
-- SPDX-License-Identifier: Apache-2.0
-- =================================================================================================
-- Module:
--   N_CNT saturating event counters of CNT_BITS bits kept in block RAM (canopen_sdp_ram) with
--   one shared incrementer.
-- Purpose:
--   The statistics counters of canopen_host_regs and canopen_pdo_engine without a 32-bit
--   register and a 32-bit incrementer per counter:
--   * Events: inc_i carries, for every counter, an amount (INC_BITS bits, 0 = no event) in
--     every cycle, for any number of counters at once. Each counter adds its amounts into a
--     small pending count (flip-flops).
--   * Sweep: a pointer visits slot 0, 1, .., S - 1, 0, .. (S = max(N_CNT, 3)), one slot per
--     cycle. A visit takes the pending count of the slot's counter into a three-stage
--     read-modify-write pipeline (read the RAM word, add the low half and register the carry,
--     add the carry to the high half and saturate, write). The pending count restarts with the
--     amount of the visit cycle, so no event is lost. Pending width: a counter is visited every
--     S cycles, so it never holds more than S * (2**INC_BITS - 1).
--   * Saturation: a sum above 2**CNT_BITS - 1 writes all ones; the counter stays there.
--   * Clear (clr_i): every counter reads 0 from the next cycle on; the amounts of the clear
--     cycle are dropped (a clear wins over an event in the same cycle). A per-counter "zero"
--     flag masks the RAM word until the sweep has written the counter again; the pipeline
--     stages in flight are cancelled.
--   * Host read port: a second RAM copy (same writes) read at rd_addr_i, registered read data:
--     rd_data_o is the count of rd_addr_i of the previous cycle (0 for addresses >= N_CNT).
--     Lag: a read with the address in cycle r returns the exact (saturated) count of the
--     events of the cycles before cycle c, for one c with r - (S + 2) <= c <= r; after a clear
--     in cycle x, c > x. An event is therefore visible in every read with the address at least
--     S + 3 cycles after the event cycle.
--   Timing and the proofs: docs/canopen_counter_bank.md.
-- =================================================================================================

library ieee;
    use ieee.std_logic_1164.all;
    use ieee.numeric_std.all;

library work;
    use work.canopen_util_pkg.all;

entity canopen_counter_bank is
    generic (
        N_CNT    : positive range 1 to 64 := 11; -- counters
        CNT_BITS : positive range 2 to 32 := 32; -- bits per counter (saturate at all ones)
        INC_BITS : positive range 1 to 4  := 2   -- bits of a counter's amount per cycle
    );
    port (
        clk_i     : in    std_logic;                                               -- clock
        rst_n_i   : in    std_logic;                                               -- reset
        inc_i     : in    std_logic_vector(N_CNT * INC_BITS - 1 downto 0);         -- amounts
        clr_i     : in    std_logic;                                               -- clear
        rd_addr_i : in    std_logic_vector(max_nat(1, clog2(N_CNT)) - 1 downto 0); -- counter
        rd_data_o : out   std_logic_vector(CNT_BITS - 1 downto 0)                  -- count
    );
end entity canopen_counter_bank;

architecture rtl of canopen_counter_bank is

    -- ---------------------------------------------------------------------------------------------
    -- Elaboration-time configuration
    -- ---------------------------------------------------------------------------------------------

    -- sweep period: one slot per cycle; at least the read-to-write distance of the pipeline
    -- (read in cycle c0, written at the end of cycle c0 + 2), so that a visit always reads the
    -- word the previous visit wrote
    constant slots_c : positive := max_nat(N_CNT, 3);
    -- largest amount of one cycle, largest pending count (one sweep period of amounts)
    constant amt_max_c   : positive := 2 ** INC_BITS - 1;
    constant pend_max_c  : positive := slots_c * amt_max_c;
    constant pend_bits_c : positive := clog2(pend_max_c + 1);
    -- the incrementer is split in a low and a high half with a registered carry
    constant lo_bits_c : positive := (CNT_BITS + 1) / 2;
    constant hi_bits_c : positive := CNT_BITS - lo_bits_c;
    -- carry out of the low half: at most (2**lo_bits_c - 1 + pend_max_c) / 2**lo_bits_c
    constant cy_max_c  : positive := (2 ** lo_bits_c - 1 + pend_max_c) / 2 ** lo_bits_c;
    constant cy_bits_c : positive := clog2(cy_max_c + 1);
    -- low sum: low half plus the pending count; high sum: high half plus the carry
    constant s1_bits_c : positive := lo_bits_c + cy_bits_c;
    constant s2_bits_c : positive := max_nat(hi_bits_c, cy_bits_c) + 1;
    -- host read address width
    constant ra_bits_c : positive := max_nat(1, clog2(N_CNT));

    function check_config return boolean is
    begin

        assert pend_bits_c <= s1_bits_c
            report "canopen_counter_bank: pending count wider than the low sum"
            severity failure;
        report "canopen_counter_bank: " & integer'image(N_CNT) & " counters x "
               & integer'image(CNT_BITS) & " bits, sweep period " & integer'image(slots_c)
               & " cycles, pending counts " & integer'image(pend_bits_c) & " bits, read lag <= "
               & integer'image(slots_c + 2) & " cycles"
            severity note;
        return true;

    end function check_config;

    constant config_ok_c : boolean := check_config;

    -- ---------------------------------------------------------------------------------------------
    -- Signals
    -- ---------------------------------------------------------------------------------------------

    type pend_arr_t is array (0 to N_CNT - 1) of unsigned(pend_bits_c - 1 downto 0);

    constant inc_zero_c : std_logic_vector(INC_BITS - 1 downto 0) := (others => '0');

    -- sweep pointer, binary (RAM address) and one-hot (counter select)
    signal ptr : natural range 0 to slots_c - 1;
    signal hot : std_logic_vector(slots_c - 1 downto 0);
    -- pending amounts per counter
    signal pend : pend_arr_t;
    -- counter reads as 0 (reset, clear) until the sweep writes it
    signal zero : std_logic_vector(N_CNT - 1 downto 0);
    -- stage 0 (combinational): pending count, zero flag and validity of the visited slot
    signal take0  : unsigned(pend_bits_c - 1 downto 0);
    signal zero0  : std_logic;
    signal valid0 : std_logic;
    -- stage 1 (RAM word being read): valid, slot, zero flag, pending count taken
    signal v1 : std_logic;
    signal a1 : natural range 0 to slots_c - 1;
    signal z1 : std_logic;
    signal t1 : unsigned(pend_bits_c - 1 downto 0);
    -- sweep copy of the RAM: read data of the slot of stage 1
    signal sw_q : std_logic_vector(CNT_BITS - 1 downto 0);
    -- stage 2: valid, slot, low sum, its carry, high half
    signal v2  : std_logic;
    signal a2  : natural range 0 to slots_c - 1;
    signal lo2 : unsigned(lo_bits_c - 1 downto 0);
    signal cy2 : unsigned(cy_bits_c - 1 downto 0);
    signal hi2 : unsigned(hi_bits_c - 1 downto 0);
    -- write-back word of stage 2
    signal wdata : std_logic_vector(CNT_BITS - 1 downto 0);
    -- host read: RAM address, the address is a counter, registered zero mask, copy read data
    signal ra     : natural range 0 to slots_c - 1;
    signal ra_ok  : std_logic;
    signal rz     : std_logic;
    signal host_q : std_logic_vector(CNT_BITS - 1 downto 0);

begin

    -- ---------------------------------------------------------------------------------------------
    -- Stage 0: the visited slot's pending count and zero flag (AND-OR on the one-hot pointer)
    -- ---------------------------------------------------------------------------------------------
    take_proc : process (hot, pend, zero) is

        variable t : unsigned(pend_bits_c - 1 downto 0);
        variable z : std_logic;
        variable v : std_logic;

    begin

        t := (others => '0');
        z := '0';
        v := '0';

        for k in 0 to N_CNT - 1 loop

            if hot(k) = '1' then
                t := t or pend(k);
                z := z or zero(k);
                v := '1';
            end if;

        end loop;

        -- a slot without a counter (N_CNT < 3) reads as zero and writes nothing
        take0  <= t;
        zero0  <= z or not v;
        valid0 <= v;

    end process take_proc;

    -- ---------------------------------------------------------------------------------------------
    -- Control: sweep pointer, pending counts, zero flags, stage valid bits
    -- ---------------------------------------------------------------------------------------------
    ctrl_proc : process (clk_i, rst_n_i) is

        variable amt_v : unsigned(INC_BITS - 1 downto 0);

    begin

        if rst_n_i = '0' then
            ptr  <= 0;
            hot  <= (0 => '1', others => '0');
            pend <= (others => (others => '0'));
            zero <= (others => '1');
            v1   <= '0';
            v2   <= '0';
        elsif rising_edge(clk_i) then
            if ptr = slots_c - 1 then
                ptr <= 0;
            else
                ptr <= ptr + 1;
            end if;
            hot <= hot(slots_c - 2 downto 0) & hot(slots_c - 1);

            -- a visit takes the pending count; the amounts of this cycle start the next one
            -- (an amount of 0 leaves the count as it is: the same logic as adding 0, but the
            -- simulator skips the adder of every idle counter in every cycle)
            for k in 0 to N_CNT - 1 loop

                amt_v := unsigned(inc_i(INC_BITS * k + INC_BITS - 1 downto INC_BITS * k));
                if clr_i = '1' then
                    pend(k) <= (others => '0');
                elsif hot(k) = '1' then
                    pend(k) <= resize(amt_v, pend_bits_c);
                elsif inc_i(INC_BITS * k + INC_BITS - 1 downto INC_BITS * k) /= inc_zero_c then
                    pend(k) <= pend(k) + amt_v;
                end if;

            end loop;

            v1 <= valid0 and not clr_i;
            v2 <= v1 and not clr_i;

            -- the zero flag stays until the write of the counter's first visit lands
            if clr_i = '1' then
                zero <= (others => '1');
            elsif v2 = '1' then
                zero(a2) <= '0';
            end if;
        end if;

    end process ctrl_proc;

    -- ---------------------------------------------------------------------------------------------
    -- Datapath: stage registers qualified by v1 / v2 (no reset)
    -- ---------------------------------------------------------------------------------------------
    data_proc : process (clk_i) is

        variable base_v : unsigned(CNT_BITS - 1 downto 0);
        variable s1_v   : unsigned(s1_bits_c - 1 downto 0);

    begin

        if rising_edge(clk_i) then
            -- stage 0 -> 1
            a1 <= ptr;
            z1 <= zero0;
            t1 <= take0;

            -- stage 1 -> 2: low half plus the pending count, carry registered; a counter that
            -- reads as 0 takes the pending count alone (a select after the adder, which works
            -- on the RAM word: the zero flag is not in the adder's path)
            base_v := unsigned(sw_q);
            s1_v   := resize(base_v(lo_bits_c - 1 downto 0), s1_bits_c) + resize(t1, s1_bits_c);
            if z1 = '1' then
                base_v := (others => '0');
                s1_v   := resize(t1, s1_bits_c);
            end if;
            a2  <= a1;
            lo2 <= s1_v(lo_bits_c - 1 downto 0);
            cy2 <= s1_v(s1_bits_c - 1 downto lo_bits_c);
            hi2 <= base_v(CNT_BITS - 1 downto lo_bits_c);
        end if;

    end process data_proc;

    -- stage 2: high half plus the carry; all ones when the sum does not fit
    wdata_proc : process (cy2, hi2, lo2) is

        variable s2_v : unsigned(s2_bits_c - 1 downto 0);

    begin

        s2_v := resize(hi2, s2_bits_c) + resize(cy2, s2_bits_c);

        if s2_v(s2_bits_c - 1 downto hi_bits_c) /= 0 then
            wdata <= (others => '1');
        else
            wdata <= std_logic_vector(s2_v(hi_bits_c - 1 downto 0)) & std_logic_vector(lo2);
        end if;

    end process wdata_proc;

    -- ---------------------------------------------------------------------------------------------
    -- The two RAM copies: sweep read port and host read port, the same writes
    -- ---------------------------------------------------------------------------------------------
    sweep_ram_inst : entity work.canopen_sdp_ram
        generic map (
            DEPTH => slots_c,
            WIDTH => CNT_BITS
        )
        port map (
            clk_i   => clk_i,
            we_i    => v2,
            waddr_i => a2,
            wdata_i => wdata,
            re_i    => '1',
            raddr_i => ptr,
            rdata_o => sw_q
        );

    host_ram_inst : entity work.canopen_sdp_ram
        generic map (
            DEPTH => slots_c,
            WIDTH => CNT_BITS
        )
        port map (
            clk_i   => clk_i,
            we_i    => v2,
            waddr_i => a2,
            wdata_i => wdata,
            re_i    => '1',
            raddr_i => ra,
            rdata_o => host_q
        );

    -- ---------------------------------------------------------------------------------------------
    -- Host read: address decode, zero mask registered with the RAM read
    -- ---------------------------------------------------------------------------------------------
    ra_proc : process (rd_addr_i) is

        variable n : natural range 0 to 2 ** ra_bits_c - 1;

    begin

        n := to_integer(unsigned(rd_addr_i));

        if n < N_CNT then
            ra    <= n;
            ra_ok <= '1';
        else
            ra    <= 0;
            ra_ok <= '0';
        end if;

    end process ra_proc;

    rz_proc : process (clk_i, rst_n_i) is
    begin

        if rst_n_i = '0' then
            rz <= '1';
        elsif rising_edge(clk_i) then
            rz <= not ra_ok or zero(ra);
        end if;

    end process rz_proc;

    rd_data_o <= (others => '0') when rz = '1' else
                 host_q;

end architecture rtl;
