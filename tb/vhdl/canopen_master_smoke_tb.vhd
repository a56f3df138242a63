-- =================================================================================================
-- Title    : canopen_master_smoke_tb
-- Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
-- SPDX-License-Identifier: Apache-2.0
-- =================================================================================================
-- Module:
--   VHDL-only smoke test of canopen_master_top for simulators without cocotb (the FuseSoC `sim`
--   target runs it on GHDL through edalize; any VHDL-2008 simulator can run it).
-- Purpose:
--   Proves that the packaged file list elaborates and that the core is alive, with no MCP2510
--   attached (SO stuck high, as with a pull-up and no chip):
--     1. ID and VERSION read back the reset words of the register package, with read latency 2;
--     2. TIME_US counts microseconds (10 us of simulated time = 10 counts);
--     3. the first SPI byte after reset is the MCP2510 RESET instruction (C0h);
--     4. the controller's configuration check fails, it retries, and the core reports the dead
--        chip: STATUS.INIT_FAIL = 1, STATUS.INIT_DONE = 0, IRQ_STATUS.INIT = 1, irq_o high
--        (IRQ_ENABLE.INIT set), and irq_o falls after the write-1-to-clear.
--   Every wait is bounded; a failed check stops the simulation with severity failure (non-zero
--   exit), success prints "canopen_master_smoke_tb: PASS" and calls std.env.finish.
-- =================================================================================================

library ieee;
    use ieee.std_logic_1164.all;
    use ieee.numeric_std.all;

library std;
    use std.env.all;

library work;
    use work.canopen_regs_pkg.all;
    use work.mcp2510_pkg.all;

entity canopen_master_smoke_tb is
end entity canopen_master_smoke_tb;

architecture sim of canopen_master_smoke_tb is

    constant CLK_PERIOD_C : time := 20 ns; -- 50 MHz, the core's default CLK_FREQ_HZ
    -- init attempts (1 + 3 retries) of about 100 us each with a 5 MHz SCK; generous bound
    constant INIT_TIMEOUT_C : time := 5 ms;

    signal clk         : std_logic;
    signal rst_n       : std_logic;
    signal address     : std_logic_vector(7 downto 0);
    signal read        : std_logic;
    signal write       : std_logic;
    signal writedata   : std_logic_vector(31 downto 0);
    signal byteenable  : std_logic_vector(3 downto 0);
    signal readdata    : std_logic_vector(31 downto 0);
    signal readdatavld : std_logic;
    signal irq         : std_logic;
    signal spi_cs_n    : std_logic;
    signal spi_sck     : std_logic;
    signal spi_mosi    : std_logic;
    signal mcp_txrts_n : std_logic_vector(2 downto 0);
    signal mcp_reset_n : std_logic;
    signal fsm_state   : std_logic_vector(3 downto 0);
    signal ctrl_state  : std_logic_vector(4 downto 0);
    signal first_byte  : std_logic_vector(7 downto 0);
    signal first_done  : boolean;
    signal done        : boolean; -- boolean'left = false: the clock runs until done

begin

    clock_proc : process is
    begin

        clk <= '0';

        while not done loop

            wait for CLK_PERIOD_C / 2;
            clk <= not clk;

        end loop;

        wait;

    end process clock_proc;

    dut_inst : entity work.canopen_master_top
        port map (
            clk_i               => clk,
            rst_n_i             => rst_n,
            avs_address_i       => address,
            avs_read_i          => read,
            avs_write_i         => write,
            avs_writedata_i     => writedata,
            avs_byteenable_i    => byteenable,
            avs_readdata_o      => readdata,
            avs_readdatavalid_o => readdatavld,
            irq_o               => irq,
            spi_cs_n_o          => spi_cs_n,
            spi_sck_o           => spi_sck,
            spi_mosi_o          => spi_mosi,
            spi_miso_i          => '1',
            mcp_int_n_i         => '1',
            mcp_rx0bf_n_i       => '1',
            mcp_rx1bf_n_i       => '1',
            mcp_txrts_n_o       => mcp_txrts_n,
            mcp_reset_n_o       => mcp_reset_n,
            fsm_state_o         => fsm_state,
            ctrl_state_o        => ctrl_state
        );

    -- first byte on SI after reset (SPI mode 0,0: sampled on the rising SCK edge, MSB first)
    spi_monitor_proc : process is
    begin

        first_byte <= (others => '0');
        first_done <= false;
        wait until spi_cs_n = '0';

        for i in 7 downto 0 loop

            wait until rising_edge(spi_sck);
            first_byte(i) <= spi_mosi;

        end loop;

        first_done <= true;
        wait;

    end process spi_monitor_proc;

    stimulus_proc : process is

        -- one Avalon read: command for one cycle, data exactly two cycles later (readLatency 2)

        procedure avs_read (addr : natural; data : out std_logic_vector(31 downto 0)) is
        begin

            wait until rising_edge(clk);
            address <= std_logic_vector(to_unsigned(addr, address'length));
            read    <= '1';
            wait until rising_edge(clk);
            read    <= '0';
            wait until rising_edge(clk);
            assert readdatavld = '0'
                report "readdatavalid high one cycle after the read (read latency is 2)"
                severity failure;
            wait until rising_edge(clk);
            assert readdatavld = '1'
                report "readdatavalid not high two cycles after the read"
                severity failure;
            data    := readdata;

        end procedure avs_read;

        procedure avs_write (addr : natural; data : std_logic_vector(31 downto 0)) is
        begin

            wait until rising_edge(clk);
            address   <= std_logic_vector(to_unsigned(addr, address'length));
            writedata <= data;
            write     <= '1';
            wait until rising_edge(clk);
            write     <= '0';

        end procedure avs_write;

        variable data    : std_logic_vector(31 downto 0);
        variable t0_us   : unsigned(31 downto 0);
        variable elapsed : unsigned(31 downto 0);
        variable t_irq   : time;

    begin

        rst_n      <= '0';
        address    <= (others => '0');
        read       <= '0';
        write      <= '0';
        writedata  <= (others => '0');
        byteenable <= (others => '1');
        wait for 10 * CLK_PERIOD_C;
        wait until rising_edge(clk);
        rst_n      <= '1';
        wait for 5 * CLK_PERIOD_C;

        -- 1. identification
        avs_read(REG_ID_C, data);
        assert data = ID_RESET_C
            report "ID reads " & to_hstring(data) & ", expected " & to_hstring(ID_RESET_C)
            severity failure;
        avs_read(REG_VERSION_C, data);
        assert data = VERSION_RESET_C
            report "VERSION reads " & to_hstring(data) & ", expected " & to_hstring(VERSION_RESET_C)
            severity failure;

        -- 2. microsecond time base
        avs_read(REG_TIME_US_C, data);
        t0_us   := unsigned(data);
        wait for 10 us;
        avs_read(REG_TIME_US_C, data);
        elapsed := unsigned(data) - t0_us;
        assert elapsed = 10
            report "TIME_US advanced by " & integer'image(to_integer(elapsed)) & " in 10 us"
            severity failure;

        -- 3. + 4. dead chip: enable the INIT interrupt and wait for it
        data                    := (others => '0');
        data(IRQ_ENABLE_INIT_C) := '1';
        avs_write(REG_IRQ_ENABLE_C, data);

        if irq /= '1' then
            wait until irq = '1' for INIT_TIMEOUT_C;
        end if;

        assert irq = '1'
            report "no INIT interrupt within " & time'image(INIT_TIMEOUT_C)
            severity failure;
        t_irq := now;                   -- the core's figure, not the bus cycles after it
        assert first_done and first_byte = MCP_INSTR_RESET_C
            report "first SPI byte " & to_hstring(first_byte) & ", expected RESET "
                   & to_hstring(MCP_INSTR_RESET_C)
            severity failure;
        assert mcp_reset_n = '1'
            report "RESET# still asserted"
            severity failure;

        avs_read(REG_STATUS_C, data);
        assert data(STATUS_INIT_FAIL_C) = '1' and data(STATUS_INIT_DONE_C) = '0'
            report "STATUS " & to_hstring(data) & ": expected INIT_FAIL = 1, INIT_DONE = 0"
            severity failure;
        avs_read(REG_IRQ_STATUS_C, data);
        assert data(IRQ_STATUS_INIT_C) = '1'
            report "IRQ_STATUS " & to_hstring(data) & ": INIT flag not set"
            severity failure;

        data                    := (others => '0');
        data(IRQ_STATUS_INIT_C) := '1';
        avs_write(REG_IRQ_STATUS_C, data);
        wait until rising_edge(clk);
        wait until rising_edge(clk);
        assert irq = '0'
            report "irq_o still high after clearing IRQ_STATUS.INIT"
            severity failure;

        report "canopen_master_smoke_tb: PASS (init failure reported at "
               & to_string(t_irq, us) & ")";
        done <= true;
        finish;
        wait;

    end process stimulus_proc;

end architecture sim;
