-- =================================================================================================
-- Title    : mcp2510_instr
-- Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
-- SPDX-License-Identifier: Apache-2.0
-- =================================================================================================
-- Module:
--   MCP2510 instruction executor (framing layer between mcp2510_ctrl and the SPI engine).
-- Purpose:
--   Executes one MCP2510 SPI instruction per command as one gapless SPI transaction:
--     instruction byte, [address byte], data bytes.
--   cmd_instr_i is the full first byte; an address byte follows for READ, WRITE and BIT MODIFY.
--   cmd_len_i data bytes follow: taken from cmd_wbyte_i (WRITE, BIT MODIFY: mask then data) or
--   clocked out as 0x00 while the chip answers (READ, READ STATUS). The bytes the chip sends
--   during the data phase are returned in rsp_rdata_o (byte k at bits 8k+7..8k), which holds
--   them from rsp_valid_o until the next command is accepted (mcp2510_ctrl decodes an RX frame
--   from it without a copy).
--   RX-buffer mode (cmd_rxbuf_i = '1', with READ at RXBnSIDH): the length is taken from the
--   received data. After the DLC byte (data byte 4) only as many data bytes are read as the
--   frame carries (0 for a remote frame, else DLC, at most 8), so a short frame costs fewer SPI
--   bytes. The transaction ends through the engine's tx_end_i, without a dummy byte.
--   The block knows the MCP2510 framing, not what the registers mean.
--   Write bytes are asked for one at a time: cmd_widx_o is the index k of the data byte the SPI
--   engine takes next, and the caller answers with that byte on cmd_wbyte_i in the same cycle
--   (combinational: mcp2510_ctrl selects it from its state and frame registers, which do not
--   change before the response). No 14-byte write vector is built or copied anywhere.
-- =================================================================================================

library ieee;
    use ieee.std_logic_1164.all;
    use ieee.numeric_std.all;

library work;
    use work.mcp2510_pkg.all;

entity mcp2510_instr is
    generic (
        CLK_FREQ_HZ   : positive                  := 50_000_000; -- clk_i frequency [Hz]
        SPI_SCLK_HZ   : positive                  := 5_000_000;  -- max SCK [Hz], <= 5 MHz
        CS_SETUP_NS   : natural range 0 to 10_000 := 100;        -- tCSS [ns]
        CS_HOLD_NS    : natural range 0 to 10_000 := 100;        -- tCSH [ns]
        CS_DISABLE_NS : natural range 0 to 10_000 := 100         -- tCSD [ns]
    );
    port (
        -- clock and reset
        clk_i   : in    std_logic; -- system clock
        rst_n_i : in    std_logic; -- async reset, active low
        -- command
        cmd_valid_i : in    std_logic;                    -- start a command (when ready)
        cmd_ready_o : out   std_logic;                    -- idle, a command is accepted
        cmd_instr_i : in    std_logic_vector(7 downto 0); -- instruction byte
        cmd_addr_i  : in    std_logic_vector(7 downto 0); -- register address
        cmd_len_i   : in    std_logic_vector(3 downto 0); -- data bytes (0..14)
        cmd_rxbuf_i : in    std_logic;                    -- READ of an RX buffer: DLC-limited
        cmd_widx_o  : out   std_logic_vector(3 downto 0); -- data byte wanted next (0..13)
        cmd_wbyte_i : in    std_logic_vector(7 downto 0); -- that byte (WRITE, BIT MODIFY)
        -- response
        rsp_valid_o : out   std_logic;                      -- strobe: command done
        rsp_rdata_o : out   std_logic_vector(111 downto 0); -- bytes read in the data phase
        rsp_len_o   : out   std_logic_vector(3 downto 0);   -- data bytes actually transferred
        -- SPI pins
        spi_cs_n_o : out   std_logic; -- chip select, active low
        spi_sck_o  : out   std_logic; -- serial clock (mode 0,0)
        spi_mosi_o : out   std_logic; -- to MCP2510 SI
        spi_miso_i : in    std_logic  -- from MCP2510 SO
    );
end entity mcp2510_instr;

architecture rtl of mcp2510_instr is

    -- index of the DLC byte inside an RX buffer read starting at RXBnSIDH
    constant rx_dlc_idx_c  : natural := 4;
    constant rx_sidl_idx_c : natural := 1;

    -- a command is executing
    signal active : std_logic;
    -- latched command
    signal instr      : std_logic_vector(7 downto 0);
    signal addr       : std_logic_vector(7 downto 0);
    signal rxbuf_mode : std_logic;
    -- 1 or 2 header bytes (instruction [+ address])
    signal hdr_len : natural range 1 to 2;
    -- total bytes of the transaction, once known
    signal total : natural range 1 to 16;
    -- the total is final (always, except an RX-buffer read before its DLC byte arrived)
    signal total_known : std_logic;
    -- bytes handed to the engine / received from it
    signal tx_idx : natural range 0 to 16;
    -- tx_idx - hdr_len mod 16, counted beside tx_idx: the data byte index (cmd_widx_o)
    signal wr_idx : unsigned(3 downto 0);
    signal rx_idx : natural range 0 to 16;
    -- received data-phase bytes
    signal rdata : std_logic_vector(111 downto 0);
    -- end request towards the engine (RX-buffer read with no data bytes after the DLC)
    signal end_pulse : std_logic;

    -- engine handshake
    signal eng_tx_valid : std_logic;
    signal eng_tx_data  : std_logic_vector(7 downto 0);
    signal eng_tx_last  : std_logic;
    signal eng_tx_ready : std_logic;
    signal eng_rx_valid : std_logic;
    signal eng_rx_data  : std_logic_vector(7 downto 0);
    signal eng_done     : std_logic;

    -- number of header bytes of an instruction: READ, WRITE and BIT MODIFY carry an address

    function header_length (i : std_logic_vector(7 downto 0)) return natural is
    begin

        if i = MCP_INSTR_READ_C or i = MCP_INSTR_WRITE_C or i = MCP_INSTR_BIT_MODIFY_C then
            return 2;
        end if;

        return 1;

    end function header_length;

    -- data bytes still to read after the DLC byte of an RX buffer (0 for remote frames)

    function rx_data_bytes (sidl : std_logic_vector(7 downto 0);
        dlc : std_logic_vector(7 downto 0)) return natural is

        variable n : natural;

    begin

        if (sidl and MCP_SIDL_IDE_C) = x"00" then
            if (sidl and MCP_SIDL_SRR_C) /= x"00" then
                return 0;
            end if;
        elsif (dlc and MCP_DLC_RTR_C) /= x"00" then
            return 0;
        end if;

        n := to_integer(unsigned(dlc(3 downto 0)));

        if n > 8 then
            return 8;
        end if;

        return n;

    end function rx_data_bytes;

begin

    -- byte stream towards the engine ---------------------------------------------------------
    eng_tx_valid <= '1' when active = '1' and tx_idx < total else '0';
    eng_tx_last  <= '1' when total_known = '1' and tx_idx = total - 1 else '0';

    -- the write bytes are asked for one at a time: cmd_widx_o is the data byte index of tx_idx
    -- (meaningful from tx_idx = hdr_len on), the caller answers on cmd_wbyte_i in the same cycle
    cmd_widx_o <= std_logic_vector(wr_idx);

    tx_byte_proc : process (addr, cmd_wbyte_i, hdr_len, instr, tx_idx) is
    begin

        if tx_idx = 0 then
            eng_tx_data <= instr;
        elsif tx_idx = 1 and hdr_len = 2 then
            eng_tx_data <= addr;
        elsif instr = MCP_INSTR_WRITE_C or instr = MCP_INSTR_BIT_MODIFY_C then
            eng_tx_data <= cmd_wbyte_i;
        else
            eng_tx_data <= x"00";  -- dummy byte while reading
        end if;

    end process tx_byte_proc;

    -- command sequencing ------------------------------------------------------------------------
    control_proc : process (clk_i, rst_n_i) is

        variable data_idx : integer;
        variable n_data   : natural;
        variable rx_sidl  : std_logic_vector(7 downto 0);

    begin

        if rst_n_i = '0' then
            active      <= '0';
            tx_idx      <= 0;
            wr_idx      <= (others => '0');
            rx_idx      <= 0;
            total       <= 1;
            total_known <= '1';
            end_pulse   <= '0';
            rsp_valid_o <= '0';
        elsif rising_edge(clk_i) then
            rsp_valid_o <= '0';
            end_pulse   <= '0';

            if active = '0' then
                if cmd_valid_i = '1' then
                    instr      <= cmd_instr_i;
                    addr       <= cmd_addr_i;
                    rxbuf_mode <= cmd_rxbuf_i;
                    hdr_len    <= header_length(cmd_instr_i);
                    tx_idx     <= 0;
                    wr_idx     <= to_unsigned((16 - header_length(cmd_instr_i)) mod 16, 4);
                    rx_idx     <= 0;
                    rdata      <= (others => '0');
                    active     <= '1';
                    if cmd_rxbuf_i = '1' then
                        -- read up to and including the DLC byte, then decide
                        total       <= 2 + rx_dlc_idx_c + 1;
                        total_known <= '0';
                    else
                        total       <= header_length(cmd_instr_i)
                                       + to_integer(unsigned(cmd_len_i));
                        total_known <= '1';
                    end if;
                end if;
            else
                if eng_tx_valid = '1' and eng_tx_ready = '1' then
                    tx_idx <= tx_idx + 1;
                    wr_idx <= wr_idx + 1;
                end if;

                if eng_rx_valid = '1' then
                    rx_sidl  := rdata(8 * rx_sidl_idx_c + 7 downto 8 * rx_sidl_idx_c);
                    rx_idx   <= rx_idx + 1;
                    data_idx := rx_idx - hdr_len;
                    if data_idx >= 0 and data_idx < 14 then
                        rdata(8 * data_idx + 7 downto 8 * data_idx) <= eng_rx_data;
                    end if;
                    -- RX-buffer read: the DLC byte fixes the length
                    if rxbuf_mode = '1' and total_known = '0' and data_idx = rx_dlc_idx_c then
                        n_data      := rx_data_bytes(rx_sidl, eng_rx_data);
                        total       <= hdr_len + rx_dlc_idx_c + 1 + n_data;
                        total_known <= '1';
                        if n_data = 0 then
                            end_pulse <= '1';
                        end if;
                    end if;
                end if;

                if eng_done = '1' then
                    active      <= '0';
                    rsp_valid_o <= '1';
                    rsp_len_o   <= std_logic_vector(to_unsigned(total - hdr_len, 4));
                end if;
            end if;
        end if;

    end process control_proc;

    rsp_rdata_o <= rdata;
    cmd_ready_o <= not active;

    -- SPI engine --------------------------------------------------------------------------------
    spi_inst : entity work.mcp2510_spi_master
        generic map (
            CLK_FREQ_HZ   => CLK_FREQ_HZ,
            SPI_SCLK_HZ   => SPI_SCLK_HZ,
            CS_SETUP_NS   => CS_SETUP_NS,
            CS_HOLD_NS    => CS_HOLD_NS,
            CS_DISABLE_NS => CS_DISABLE_NS
        )
        port map (
            clk_i      => clk_i,
            rst_n_i    => rst_n_i,
            tx_valid_i => eng_tx_valid,
            tx_data_i  => eng_tx_data,
            tx_last_i  => eng_tx_last,
            tx_ready_o => eng_tx_ready,
            tx_end_i   => end_pulse,
            rx_valid_o => eng_rx_valid,
            rx_data_o  => eng_rx_data,
            busy_o     => open,
            done_o     => eng_done,
            spi_cs_n_o => spi_cs_n_o,
            spi_sck_o  => spi_sck_o,
            spi_mosi_o => spi_mosi_o,
            spi_miso_i => spi_miso_i
        );

end architecture rtl;
