-- =================================================================================================
-- Title    : canopen_fifo
-- Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
-- SPDX-License-Identifier: Apache-2.0
-- =================================================================================================
-- Module:
--   Generic first-word-fall-through FIFO (WIDTH bits x DEPTH entries) on one canopen_sdp_ram
--   (block RAM); the one FIFO of the core (RX frames in mcp2510_ctrl, EMCY messages in
--   canopen_node_monitor).
-- Behaviour:
--   * Push: data_i is stored at the rising edge where push_i = '1' and the FIFO has room (fewer
--     than DEPTH entries stored, counting the one written in the previous cycle, or a pop in the
--     same cycle). A push without room is refused: nothing is stored, ovf_o = '1' in that cycle
--     (a combinational strobe, so that the user can count the loss) and the stored entries stay.
--   * Head: the RAM is read every cycle at the address of the next head, and its output
--     register is the head (data_o). An entry written at edge e is counted in count_o (and
--     empty_o falls) at edge e + 1, when data_o shows it: push to visible = 2 rising edges.
--     data_o is undefined while empty_o = '1'.
--   * Pop: pop_i = '1' drops the head at that edge (ignored while empty_o = '1'); the next head
--     shows from the next edge on (a pop every cycle drains one entry per cycle).
--   * full_o: DEPTH entries stored (including the one written in the previous cycle); a push is
--     then accepted only together with a pop.
--   * Any DEPTH 1..1024 (not only powers of two); rst_n_i empties it (the RAM has no reset).
--   * MIN_RAM_WORDS: the RAM is declared with max(DEPTH, MIN_RAM_WORDS) words, the words past
--     DEPTH never addressed. A shallow, wide FIFO costs the same M9Ks either way (an M9K has
--     256 words at x36); a flow that maps memories by fill ratio (yosys: at least 2 % of the
--     M9Ks used) then takes it as block RAM instead of DEPTH x WIDTH flip-flops.
-- =================================================================================================

library ieee;
    use ieee.std_logic_1164.all;
    use ieee.numeric_std.all;

library work;
    use work.canopen_util_pkg.all;

entity canopen_fifo is
    generic (
        WIDTH         : positive                 := 8; -- bits per entry
        DEPTH         : positive range 1 to 1024 := 4; -- entries
        MIN_RAM_WORDS : natural range 0 to 1024  := 0  -- RAM words at least (see above)
    );
    port (
        clk_i   : in    std_logic;                                      -- system clock
        rst_n_i : in    std_logic;                                      -- async reset, active low
        push_i  : in    std_logic;                                      -- store data_i
        data_i  : in    std_logic_vector(WIDTH - 1 downto 0);           -- entry to store
        full_o  : out   std_logic;                                      -- no room without a pop
        ovf_o   : out   std_logic;                                      -- push_i refused (full)
        pop_i   : in    std_logic;                                      -- drop the head
        empty_o : out   std_logic;                                      -- no entry visible
        data_o  : out   std_logic_vector(WIDTH - 1 downto 0);           -- head (when not empty)
        count_o : out   std_logic_vector(clog2(DEPTH + 1) - 1 downto 0) -- entries visible
    );
end entity canopen_fifo;

architecture rtl of canopen_fifo is

    constant ram_words_c : positive := max_nat(DEPTH, MIN_RAM_WORDS);

    subtype ptr_t is natural range 0 to DEPTH - 1;

    -- write and read (head) pointers, read address of the next cycle
    signal wr     : ptr_t;
    signal rd     : ptr_t;
    signal rd_nxt : ptr_t;
    -- entries visible at the head side
    signal count : natural range 0 to DEPTH;
    -- an entry was written at the previous edge (visible from the next one)
    signal push_d : std_logic;
    -- entries stored, including the one written at the previous edge
    signal fill : natural range 0 to DEPTH + 1;
    -- accepted pop and push of this cycle
    signal pop_ok  : std_logic;
    signal push_ok : std_logic;
    -- RAM write enable as a signal (port-map actuals are names)
    signal one : std_logic;

    function next_ptr (p : ptr_t) return ptr_t is
    begin

        if p = DEPTH - 1 then
            return 0;
        end if;

        return p + 1;

    end function next_ptr;

begin

    one    <= '1';
    pop_ok <= '1' when pop_i = '1' and count /= 0 else '0';
    fill   <= count + 1 when push_d = '1' else count;

    push_ok <= '1' when push_i = '1' and (fill < DEPTH or pop_ok = '1') else '0';
    rd_nxt  <= next_ptr(rd) when pop_ok = '1' else rd;

    ctrl_proc : process (clk_i, rst_n_i) is
    begin

        if rst_n_i = '0' then
            wr     <= 0;
            rd     <= 0;
            count  <= 0;
            push_d <= '0';
        elsif rising_edge(clk_i) then
            if push_ok = '1' then
                wr <= next_ptr(wr);
            end if;
            rd     <= rd_nxt;
            push_d <= push_ok;
            if push_d = '1' and pop_ok = '0' then
                count <= count + 1;
            elsif push_d = '0' and pop_ok = '1' then
                count <= count - 1;
            end if;
        end if;

    end process ctrl_proc;

    -- read every cycle at the next head: the RAM's output register is the head
    ram_inst : entity work.canopen_sdp_ram
        generic map (
            DEPTH => ram_words_c,
            WIDTH => WIDTH
        )
        port map (
            clk_i   => clk_i,
            we_i    => push_ok,
            waddr_i => wr,
            wdata_i => data_i,
            re_i    => one,
            raddr_i => rd_nxt,
            rdata_o => data_o
        );

    full_o  <= '1' when fill >= DEPTH else '0';
    ovf_o   <= '1' when push_i = '1' and push_ok = '0' else '0';
    empty_o <= '1' when count = 0 else '0';
    count_o <= std_logic_vector(to_unsigned(count, count_o'length));

end architecture rtl;
