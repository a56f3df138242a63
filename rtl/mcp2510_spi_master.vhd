-- =================================================================================================
-- Title    : mcp2510_spi_master
-- Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
-- SPDX-License-Identifier: Apache-2.0
-- =================================================================================================
-- Module:
--   Byte-stream SPI master (mode 0,0, MSB first) for the MCP2510 CAN controller.
-- Purpose:
--   One transaction = CS low, N bytes shifted out on MOSI and in from MISO back to back, CS high.
--   The caller streams bytes through a valid/ready handshake (tx_valid_i / tx_ready_o); the byte
--   flagged tx_last_i ends the transaction. A one-byte holding register lets the caller present
--   the next byte while the current one shifts, so a caller that keeps tx_valid_i high gets
--   transactions of any length with no gap between bytes (the SCK period at a byte boundary is
--   the same as inside a byte). Every received byte is presented for one cycle on rx_data_o with
--   rx_valid_o (no back-pressure: the caller must take it). When the length of a transaction is
--   only known from received data (an RX buffer read that stops after the DLC byte), the caller
--   withholds the next byte and pulses tx_end_i instead: the transaction then ends as soon as the
--   bytes already accepted have been shifted (no dummy byte, no gap).
--   The block knows nothing about MCP2510 instructions; it only honours the chip's electrical
--   limits: SCK <= 5 MHz and the CS setup (tCSS), hold (tCSH) and disable (tCSD) times, which are
--   generics with datasheet defaults and are converted to clock cycles rounding up.
--   Timing (all in clk_i cycles, see docs/mcp2510_spi_master.md):
--     CS fall -> first SCK rise        : max(cs_setup_cycles_c, half_period_c)
--     SCK high / low                   : half_period_c each
--     last SCK fall -> CS rise         : max(cs_hold_cycles_c, 1)
--     CS high before the next CS fall  : >= max(cs_disable_cycles_c, 1)
--   MISO is registered once (input flop) and sampled with the cycle that raises SCK, so it must
--   be valid (half_period_c - 1) clock cycles after the SCK falling edge. Elaboration fails when
--   SPI_SCLK_HZ > 5 MHz or CLK_FREQ_HZ < 4 * SPI_SCLK_HZ (half period < 2 clocks); otherwise the
--   fastest SCK <= SPI_SCLK_HZ that the clock allows is used and reported as a note.
-- =================================================================================================

library ieee;
    use ieee.std_logic_1164.all;
    use ieee.numeric_std.all;

library work;
    use work.canopen_util_pkg.all;

entity mcp2510_spi_master is
    generic (
        CLK_FREQ_HZ   : positive                  := 50_000_000; -- clk_i frequency [Hz]
        SPI_SCLK_HZ   : positive                  := 5_000_000;  -- max SCK [Hz], <= 5 MHz
        CS_SETUP_NS   : natural range 0 to 10_000 := 100;        -- tCSS: CS fall to SCK [ns]
        CS_HOLD_NS    : natural range 0 to 10_000 := 100;        -- tCSH: SCK to CS rise [ns]
        CS_DISABLE_NS : natural range 0 to 10_000 := 100         -- tCSD: CS high time [ns]
    );
    port (
        -- clock and reset
        clk_i   : in    std_logic; -- system clock
        rst_n_i : in    std_logic; -- async reset, active low (synced)
        -- byte stream towards the slave (MOSI)
        tx_valid_i : in    std_logic;                    -- tx_data_i holds a byte to send
        tx_data_i  : in    std_logic_vector(7 downto 0); -- byte to send, MSB first
        tx_last_i  : in    std_logic;                    -- this byte ends the transaction
        tx_ready_o : out   std_logic;                    -- byte accepted when valid and ready
        tx_end_i   : in    std_logic;                    -- end after the accepted bytes
        -- byte stream from the slave (MISO)
        rx_valid_o : out   std_logic;                    -- one-cycle strobe: rx_data_o is valid
        rx_data_o  : out   std_logic_vector(7 downto 0); -- byte received during the last byte
        -- status
        busy_o : out   std_logic; -- transaction or CS disable time active
        done_o : out   std_logic; -- one-cycle strobe when CS goes high
        -- SPI pins
        spi_cs_n_o : out   std_logic; -- chip select, active low
        spi_sck_o  : out   std_logic; -- serial clock, idle low (mode 0,0)
        spi_mosi_o : out   std_logic; -- master out, slave in
        spi_miso_i : in    std_logic  -- master in, slave out
    );
end entity mcp2510_spi_master;

architecture rtl of mcp2510_spi_master is

    -- MCP2510 datasheet (DS21291): maximum SCK frequency at VDD = 4.5 V to 5.5 V.
    constant sclk_max_hz_c : positive := 5_000_000;

    -- SCK half period in clk_i cycles: the smallest one that keeps SCK <= SPI_SCLK_HZ.
    constant half_period_c    : positive := (CLK_FREQ_HZ + 2 * SPI_SCLK_HZ - 1)
                                               / (2 * SPI_SCLK_HZ);
    constant sclk_actual_hz_c : positive := CLK_FREQ_HZ / (2 * half_period_c);
    constant setup_wait_c     : positive := max_nat(max_nat(ns_to_cycles(CS_SETUP_NS, CLK_FREQ_HZ),
                                                            half_period_c), 1);
    constant hold_wait_c      : positive := max_nat(ns_to_cycles(CS_HOLD_NS, CLK_FREQ_HZ), 1);
    constant disable_wait_c   : positive := max_nat(ns_to_cycles(CS_DISABLE_NS, CLK_FREQ_HZ), 1);
    constant cnt_max_c        : positive := max_nat(max_nat(setup_wait_c, hold_wait_c),
                                                    max_nat(disable_wait_c, half_period_c));

    -- Elaboration-time configuration check (evaluated by simulation and synthesis alike).

    function check_config return boolean is
    begin

        assert SPI_SCLK_HZ <= sclk_max_hz_c
            report "mcp2510_spi_master: SPI_SCLK_HZ = " & integer'image(SPI_SCLK_HZ)
                   & " Hz exceeds the MCP2510 maximum SCK of 5000000 Hz"
            severity failure;
        assert CLK_FREQ_HZ >= 4 * SPI_SCLK_HZ
            report "mcp2510_spi_master: divider not achievable: CLK_FREQ_HZ = "
                   & integer'image(CLK_FREQ_HZ) & " Hz must be at least 4 x SPI_SCLK_HZ = "
                   & integer'image(4 * SPI_SCLK_HZ)
                   & " Hz (SCK half period >= 2 clocks for the registered MISO sample)"
            severity failure;
        assert false
            report "mcp2510_spi_master: SCK = " & integer'image(sclk_actual_hz_c)
                   & " Hz (half period " & integer'image(half_period_c)
                   & " clocks); CS setup/hold/disable = " & integer'image(setup_wait_c) & "/"
                   & integer'image(hold_wait_c) & "/" & integer'image(disable_wait_c)
                   & " clocks"
            severity note;
        return true;

    end function check_config;

    constant config_ok_c : boolean := check_config;

    type state_t is (
        S_IDLE,   -- CS high, waiting for the first byte
        S_SETUP,  -- CS low, MOSI holds bit 7, waiting tCSS before the first SCK rise
        S_SHIFT,  -- shifting bits: SCK toggles every half_period_c cycles
        S_STALL,  -- byte boundary reached but the next byte is not there yet: SCK held low
        S_HOLD,   -- last bit done, SCK low, waiting tCSH before CS rises
        S_DISABLE -- CS high, waiting tCSD before the next transaction may start
    );

    -- engine state
    signal state : state_t;
    -- cycles left in the current phase
    signal phase_cnt : natural range 0 to cnt_max_c - 1;
    -- index of the bit being shifted (0 = MSB)
    signal bit_cnt : natural range 0 to 7;
    -- shift register: MSB goes out on MOSI, MISO comes in at the LSB
    signal shreg : std_logic_vector(7 downto 0);
    -- the byte in shreg is the last one of the transaction
    signal shreg_last : std_logic;
    -- holding register for the next byte (filled while shreg is shifting)
    signal hold_data  : std_logic_vector(7 downto 0);
    signal hold_last  : std_logic;
    signal hold_valid : std_logic;
    -- the byte flagged tx_last_i has been accepted: accept nothing more in this transaction
    signal last_accepted : std_logic;
    -- tx_end_i seen: end the transaction at the next byte boundary
    signal end_req : std_logic;
    -- registered MISO input (one flop; MISO is driven from our own SCK)
    signal miso_q : std_logic;
    -- registered pin outputs
    signal cs_n_q : std_logic;
    signal sck_q  : std_logic;
    signal mosi_q : std_logic;
    -- handshake towards the caller
    signal tx_ready : std_logic;

begin

    -- A byte is taken straight into the shift register when idle, otherwise into the holding
    -- register while it is empty and the transaction's last byte has not been accepted yet.
    tx_ready <= '1' when state = S_IDLE else
                '1' when (state = S_SETUP or state = S_SHIFT or state = S_STALL)
                         and hold_valid = '0' and last_accepted = '0' else
                '0';

    engine_proc : process (clk_i, rst_n_i) is
    begin

        if rst_n_i = '0' then
            state         <= S_IDLE;
            phase_cnt     <= 0;
            bit_cnt       <= 0;
            shreg_last    <= '0';
            hold_valid    <= '0';
            last_accepted <= '0';
            end_req       <= '0';
            cs_n_q        <= '1';
            sck_q         <= '0';
            mosi_q        <= '0';
            rx_valid_o    <= '0';
            done_o        <= '0';
        elsif rising_edge(clk_i) then
            rx_valid_o <= '0';
            done_o     <= '0';

            -- accept a byte into the holding register during a transaction -----------------
            if tx_valid_i = '1' and tx_ready = '1' and state /= S_IDLE then
                hold_data     <= tx_data_i;
                hold_last     <= tx_last_i;
                hold_valid    <= '1';
                last_accepted <= tx_last_i;
            end if;

            if tx_end_i = '1' and state /= S_IDLE then
                end_req <= '1';
            end if;

            case state is

                -- ----------------------------------------------------------------------------
                when S_IDLE =>

                    sck_q <= '0';
                    if tx_valid_i = '1' then
                        shreg         <= tx_data_i;
                        shreg_last    <= tx_last_i;
                        last_accepted <= tx_last_i;
                        mosi_q        <= tx_data_i(7);
                        cs_n_q        <= '0';
                        bit_cnt       <= 0;
                        phase_cnt     <= setup_wait_c - 1;
                        state         <= S_SETUP;
                    end if;

                -- ----------------------------------------------------------------------------
                when S_SETUP =>

                    if phase_cnt = 0 then
                        -- first rising edge: sample bit 7 from the slave
                        sck_q     <= '1';
                        shreg     <= shreg(6 downto 0) & miso_q;
                        phase_cnt <= half_period_c - 1;
                        state     <= S_SHIFT;
                    else
                        phase_cnt <= phase_cnt - 1;
                    end if;

                -- ----------------------------------------------------------------------------
                when S_SHIFT =>

                    if phase_cnt /= 0 then
                        phase_cnt <= phase_cnt - 1;
                    elsif sck_q = '0' then
                        -- end of the low phase: rising edge, sample MISO
                        sck_q     <= '1';
                        shreg     <= shreg(6 downto 0) & miso_q;
                        phase_cnt <= half_period_c - 1;
                        if bit_cnt = 7 then
                            rx_valid_o <= '1';
                            rx_data_o  <= shreg(6 downto 0) & miso_q;
                        end if;
                    else
                        -- end of the high phase: falling edge, present the next bit
                        sck_q     <= '0';
                        phase_cnt <= half_period_c - 1;
                        if bit_cnt /= 7 then
                            bit_cnt <= bit_cnt + 1;
                            mosi_q  <= shreg(7);
                        elsif hold_valid = '1' then
                            -- byte boundary with the next byte ready: no gap
                            shreg      <= hold_data;
                            shreg_last <= hold_last;
                            hold_valid <= '0';
                            mosi_q     <= hold_data(7);
                            bit_cnt    <= 0;
                        elsif shreg_last = '1' or end_req = '1' or tx_end_i = '1' then
                            phase_cnt <= hold_wait_c - 1;
                            state     <= S_HOLD;
                        else
                            state <= S_STALL;
                        end if;
                    end if;

                -- ----------------------------------------------------------------------------
                when S_STALL =>

                    -- SCK stays low; resume with a full low phase once the next byte is in
                    if end_req = '1' or tx_end_i = '1' then
                        phase_cnt <= hold_wait_c - 1;
                        state     <= S_HOLD;
                    elsif hold_valid = '1' then
                        shreg      <= hold_data;
                        shreg_last <= hold_last;
                        hold_valid <= '0';
                        mosi_q     <= hold_data(7);
                        bit_cnt    <= 0;
                        phase_cnt  <= half_period_c - 1;
                        state      <= S_SHIFT;
                    end if;

                -- ----------------------------------------------------------------------------
                when S_HOLD =>

                    if phase_cnt = 0 then
                        cs_n_q        <= '1';
                        done_o        <= '1';
                        last_accepted <= '0';
                        end_req       <= '0';
                        phase_cnt     <= disable_wait_c - 1;
                        state         <= S_DISABLE;
                    else
                        phase_cnt <= phase_cnt - 1;
                    end if;

                -- ----------------------------------------------------------------------------
                when S_DISABLE =>

                    if phase_cnt = 0 then
                        state <= S_IDLE;
                    else
                        phase_cnt <= phase_cnt - 1;
                    end if;

            end case;

        end if;

    end process engine_proc;

    -- MISO input register (no reset: datapath, only used when sampled inside a transaction).
    -- SO is high impedance whenever the MCP2510 does not drive it (CS high, and during its own
    -- reset and oscillator start-up, when a READ may still be running): the board pulls it up
    -- (docs/mcp2510_spi_master.md), so a weak high ('H') is read as '1'; to_X01 is a plain wire
    -- in synthesis
    miso_reg_proc : process (clk_i) is
    begin

        if rising_edge(clk_i) then
            miso_q <= to_X01(spi_miso_i);
        end if;

    end process miso_reg_proc;

    tx_ready_o <= tx_ready;
    busy_o     <= '0' when state = S_IDLE else '1';
    spi_cs_n_o <= cs_n_q;
    spi_sck_o  <= sck_q;
    spi_mosi_o <= mosi_q;

end architecture rtl;
