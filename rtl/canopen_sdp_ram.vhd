-- =================================================================================================
-- Title    : canopen_sdp_ram
-- Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
-- SPDX-License-Identifier: Apache-2.0
-- =================================================================================================
-- Module:
--   Simple dual-port RAM: one write port, one read port with a registered read (latency 1),
--   one clock, no reset. The shape every synthesis tool infers as a block RAM (an M9K on
--   Cyclone III / IV E); this entity is the one place in the core that describes it, so that
--   every per-channel and per-node table, every FIFO and every counter bank uses the same
--   template.
-- Behaviour:
--   * Write: wdata_i is stored at waddr_i on the rising edge where we_i = '1'.
--   * Read: rdata_o shows the word at the raddr_i of the previous rising edge where re_i = '1'
--     (tie re_i to '1' for a read every cycle; '0' holds rdata_o, the M9K's output register
--     clock enable). Reading the address written in the same cycle returns the OLD
--     word (the M9K's "old data" read-during-write behaviour on the two ports; the users of this
--     entity never depend on the new word).
--   * Contents after power-up are undefined ('U' in simulation): every user initialises or
--     tracks validity itself (no reset, otherwise the memory would become registers).
-- =================================================================================================

library ieee;
    use ieee.std_logic_1164.all;

entity canopen_sdp_ram is
    generic (
        DEPTH : positive := 16; -- number of words
        WIDTH : positive := 8   -- bits per word
    );
    port (
        clk_i   : in    std_logic;                            -- system clock
        we_i    : in    std_logic;                            -- write enable
        waddr_i : in    natural range 0 to DEPTH - 1;         -- write address
        wdata_i : in    std_logic_vector(WIDTH - 1 downto 0); -- write data
        re_i    : in    std_logic;                            -- read enable: '0' holds rdata_o
        raddr_i : in    natural range 0 to DEPTH - 1;         -- read address (this cycle)
        rdata_o : out   std_logic_vector(WIDTH - 1 downto 0)  -- word at raddr_i (+1 cycle)
    );
end entity canopen_sdp_ram;

architecture rtl of canopen_sdp_ram is

    type mem_t is array (0 to DEPTH - 1) of std_logic_vector(WIDTH - 1 downto 0);

    signal mem : mem_t;

begin

    ram_proc : process (clk_i) is
    begin

        if rising_edge(clk_i) then
            if we_i = '1' then
                mem(waddr_i) <= wdata_i;
            end if;
            if re_i = '1' then
                rdata_o <= mem(raddr_i);
            end if;
        end if;

    end process ram_proc;

end architecture rtl;
