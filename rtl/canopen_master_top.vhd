-- =================================================================================================
-- Title    : canopen_master_top
-- Project  : canopen_master - open-source CANopen master IP core (MCP2510 over SPI)
-- SPDX-License-Identifier: Apache-2.0
-- =================================================================================================
-- Module:
--   What a user instantiates (or adds in Platform Designer): the CANopen master with its
--   Avalon-MM host interface and interrupt, driving one MCP2510 CAN controller.
-- Purpose:
--   Structural only: the reset synchroniser (asynchronous assertion, synchronous release), the
--   CANopen core (canopen_master_core: host registers, 14-state FSM, services, datapath) and the
--   MCP2510 controller (mcp2510_ctrl with its instruction executor and SPI engine).
-- =================================================================================================

library ieee;
    use ieee.std_logic_1164.all;

library work;

entity canopen_master_top is
    generic (
        CLK_FREQ_HZ     : positive                  := 50_000_000; -- clk_i frequency [Hz]
        SPI_SCLK_HZ     : positive                  := 5_000_000;  -- max SCK [Hz], <= 5 MHz
        CS_SETUP_NS     : natural range 0 to 10_000 := 100;        -- SPI tCSS [ns]
        CS_HOLD_NS      : natural range 0 to 10_000 := 100;        -- SPI tCSH [ns]
        CS_DISABLE_NS   : natural range 0 to 10_000 := 100;        -- SPI tCSD [ns]
        OSC_FREQ_HZ     : positive                  := 16_000_000; -- MCP2510 oscillator [Hz]
        CAN_BITRATE_BPS : positive                  := 1_000_000;  -- CAN bit rate [bit/s]
        MAX_NODES       : positive range 1 to 16    := 8;          -- monitored node slots
        EMCY_DEPTH      : positive range 2 to 64    := 8;          -- EMCY FIFO entries
        N_TPDO          : positive range 1 to 32    := 8;          -- PDO channels sent
        N_RPDO          : positive range 1 to 32    := 8;          -- PDO channels received
        N_SDO           : positive range 1 to 4     := 2;          -- SDO client channels
        CFG_DEPTH       : positive range 2 to 256   := 64;         -- configuration list entries
        OMNI_ENABLE     : boolean                   := true;       -- build the Omni-ID engine
        RX_FIFO_DEPTH   : positive range 1 to 16    := 4;          -- received frames buffered
        WATCHDOG_US     : positive                  := 20_000;     -- longest wait per FSM state
        RESET_WAIT_US   : positive                  := 20          -- MCP2510 start-up wait [us]
    );
    port (
        -- clock and reset
        clk_i   : in    std_logic; -- system clock
        rst_n_i : in    std_logic; -- reset, active low, asynchronous
        -- host: Avalon-MM slave (32-bit, word addressing, read latency 1) and interrupt
        avs_address_i       : in    std_logic_vector(7 downto 0);  -- word address
        avs_read_i          : in    std_logic;                     -- read
        avs_write_i         : in    std_logic;                     -- write
        avs_writedata_i     : in    std_logic_vector(31 downto 0); -- write data
        avs_byteenable_i    : in    std_logic_vector(3 downto 0);  -- byte enables
        avs_readdata_o      : out   std_logic_vector(31 downto 0); -- read data
        avs_readdatavalid_o : out   std_logic;                     -- read data valid
        irq_o               : out   std_logic;                     -- interrupt, active high
        -- MCP2510 pins
        spi_cs_n_o    : out   std_logic;                    -- CS#
        spi_sck_o     : out   std_logic;                    -- SCK
        spi_mosi_o    : out   std_logic;                    -- SI
        spi_miso_i    : in    std_logic;                    -- SO
        mcp_int_n_i   : in    std_logic;                    -- INT#
        mcp_rx0bf_n_i : in    std_logic;                    -- RX0BF#
        mcp_rx1bf_n_i : in    std_logic;                    -- RX1BF#
        mcp_txrts_n_o : out   std_logic_vector(2 downto 0); -- TX2RTS#..TX0RTS#
        mcp_reset_n_o : out   std_logic;                    -- RESET#
        -- debug
        fsm_state_o  : out   std_logic_vector(3 downto 0); -- master FSM state (St number)
        ctrl_state_o : out   std_logic_vector(4 downto 0)  -- MCP2510 sequencer state
    );
end entity canopen_master_top;

architecture rtl of canopen_master_top is

    -- reset synchroniser: asynchronous assertion, release after two clock edges
    signal rst_sync : std_logic_vector(1 downto 0);
    signal rst_n    : std_logic;

    -- core <-> controller
    signal reinit      : std_logic;
    signal init_done   : std_logic;
    signal init_fail   : std_logic;
    signal chip_lost   : std_logic;
    signal ctl_busy    : std_logic;
    signal tec         : std_logic_vector(7 downto 0);
    signal rec         : std_logic_vector(7 downto 0);
    signal eflg        : std_logic_vector(7 downto 0);
    signal tx_valid    : std_logic;
    signal tx_ready    : std_logic;
    signal tx_send     : std_logic;
    signal tx_buf      : std_logic_vector(1 downto 0);
    signal tx_txp      : std_logic_vector(1 downto 0);
    signal tx_id       : std_logic_vector(28 downto 0);
    signal tx_rtr      : std_logic;
    signal tx_dlc      : std_logic_vector(3 downto 0);
    signal tx_data     : std_logic_vector(63 downto 0);
    signal tx_fire     : std_logic_vector(2 downto 0);
    signal tx_cancel   : std_logic_vector(2 downto 0);
    signal tx_aborted  : std_logic_vector(2 downto 0);
    signal tx_pending  : std_logic_vector(2 downto 0);
    signal tx_done     : std_logic_vector(2 downto 0);
    signal tx_err      : std_logic_vector(2 downto 0);
    signal tx_errors   : std_logic;
    signal tx_drop     : std_logic_vector(2 downto 0);
    signal tx_loaded   : std_logic;
    signal tx_busy     : std_logic;
    signal rx_valid    : std_logic;
    signal rx_ready    : std_logic;
    signal rx_ide      : std_logic;
    signal rx_rtr      : std_logic;
    signal rx_id       : std_logic_vector(28 downto 0);
    signal rx_dlc      : std_logic_vector(3 downto 0);
    signal rx_data     : std_logic_vector(63 downto 0);
    signal int_valid   : std_logic;
    signal int_canintf : std_logic_vector(7 downto 0);
    signal int_eflg    : std_logic_vector(7 downto 0);
    signal rx_overflow : std_logic_vector(1 downto 0);

begin

    rst_sync_proc : process (clk_i, rst_n_i) is
    begin

        if rst_n_i = '0' then
            rst_sync <= (others => '0');
        elsif rising_edge(clk_i) then
            rst_sync <= rst_sync(0) & '1';
        end if;

    end process rst_sync_proc;

    rst_n <= rst_sync(1);

    core_inst : entity work.canopen_master_core
        generic map (
            CLK_FREQ_HZ     => CLK_FREQ_HZ,
            MAX_NODES       => MAX_NODES,
            EMCY_DEPTH      => EMCY_DEPTH,
            N_TPDO          => N_TPDO,
            N_RPDO          => N_RPDO,
            N_SDO           => N_SDO,
            CFG_DEPTH       => CFG_DEPTH,
            CAN_BITRATE_BPS => CAN_BITRATE_BPS,
            OMNI_ENABLE     => OMNI_ENABLE,
            WATCHDOG_US     => WATCHDOG_US
        )
        port map (
            clk_i               => clk_i,
            rst_n_i             => rst_n,
            avs_address_i       => avs_address_i,
            avs_read_i          => avs_read_i,
            avs_write_i         => avs_write_i,
            avs_writedata_i     => avs_writedata_i,
            avs_byteenable_i    => avs_byteenable_i,
            avs_readdata_o      => avs_readdata_o,
            avs_readdatavalid_o => avs_readdatavalid_o,
            irq_o               => irq_o,
            fsm_state_o         => fsm_state_o,
            ctl_reinit_o        => reinit,
            ctl_init_done_i     => init_done,
            ctl_init_fail_i     => init_fail,
            ctl_chip_lost_i     => chip_lost,
            ctl_busy_i          => ctl_busy,
            ctl_tec_i           => tec,
            ctl_rec_i           => rec,
            ctl_eflg_i          => eflg,
            ctl_tx_valid_o      => tx_valid,
            ctl_tx_ready_i      => tx_ready,
            ctl_tx_buf_o        => tx_buf,
            ctl_tx_txp_o        => tx_txp,
            ctl_tx_send_o       => tx_send,
            ctl_tx_id_o         => tx_id,
            ctl_tx_rtr_o        => tx_rtr,
            ctl_tx_dlc_o        => tx_dlc,
            ctl_tx_data_o       => tx_data,
            ctl_tx_fire_o       => tx_fire,
            ctl_tx_cancel_o     => tx_cancel,
            ctl_tx_aborted_i    => tx_aborted,
            ctl_tx_loaded_i     => tx_loaded,
            ctl_tx_busy_i       => tx_busy,
            ctl_tx_pending_i    => tx_pending,
            ctl_tx_done_i       => tx_done,
            ctl_tx_err_i        => tx_err,
            ctl_tx_errors_i     => tx_errors,
            ctl_tx_drop_i       => tx_drop,
            ctl_rx_valid_i      => rx_valid,
            ctl_rx_ready_o      => rx_ready,
            ctl_rx_id_i         => rx_id,
            ctl_rx_ide_i        => rx_ide,
            ctl_rx_rtr_i        => rx_rtr,
            ctl_rx_dlc_i        => rx_dlc,
            ctl_rx_data_i       => rx_data,
            ctl_int_valid_i     => int_valid,
            ctl_int_canintf_i   => int_canintf,
            ctl_int_eflg_i      => int_eflg,
            ctl_rx_overflow_i   => rx_overflow
        );

    ctrl_inst : entity work.mcp2510_ctrl
        generic map (
            CLK_FREQ_HZ     => CLK_FREQ_HZ,
            SPI_SCLK_HZ     => SPI_SCLK_HZ,
            CS_SETUP_NS     => CS_SETUP_NS,
            CS_HOLD_NS      => CS_HOLD_NS,
            CS_DISABLE_NS   => CS_DISABLE_NS,
            OSC_FREQ_HZ     => OSC_FREQ_HZ,
            CAN_BITRATE_BPS => CAN_BITRATE_BPS,
            RESET_WAIT_US   => RESET_WAIT_US,
            RX_FIFO_DEPTH   => RX_FIFO_DEPTH
        )
        port map (
            clk_i            => clk_i,
            rst_n_i          => rst_n,
            reinit_i         => reinit,
            init_done_o      => init_done,
            init_fail_o      => init_fail,
            chip_lost_o      => chip_lost,
            busy_o           => ctl_busy,
            state_o          => ctrl_state_o,
            tx_valid_i       => tx_valid,
            tx_ready_o       => tx_ready,
            tx_buf_i         => tx_buf,
            tx_txp_i         => tx_txp,
            tx_send_i        => tx_send,
            tx_id_i          => tx_id,
            tx_ide_i         => '0',
            tx_rtr_i         => tx_rtr,
            tx_dlc_i         => tx_dlc,
            tx_data_i        => tx_data,
            tx_fire_i        => tx_fire,
            tx_abort_i       => '0',
            tx_cancel_i      => tx_cancel,
            tx_loaded_o      => tx_loaded,
            tx_busy_o        => tx_busy,
            tx_pending_o     => tx_pending,
            tx_done_o        => tx_done,
            tx_err_o         => tx_err,
            tx_errors_o      => tx_errors,
            tx_arb_lost_o    => open,
            tx_aborted_o     => tx_aborted,
            tx_fire_drop_o   => tx_drop,
            rx_valid_o       => rx_valid,
            rx_ready_i       => rx_ready,
            rx_id_o          => rx_id,
            rx_ide_o         => rx_ide,
            rx_rtr_o         => rx_rtr,
            rx_dlc_o         => rx_dlc,
            rx_data_o        => rx_data,
            rx_buf_o         => open,
            int_valid_o      => int_valid,
            int_canintf_o    => int_canintf,
            int_eflg_o       => int_eflg,
            rx_overflow_o    => rx_overflow,
            err_valid_o      => open,
            err_tec_o        => tec,
            err_rec_o        => rec,
            err_eflg_o       => eflg,
            status_req_i     => '0',
            status_valid_o   => open,
            status_rdstat_o  => open,
            status_tec_o     => open,
            status_rec_o     => open,
            status_intf_o    => open,
            status_eflg_o    => open,
            status_txbctrl_o => open,
            spi_cs_n_o       => spi_cs_n_o,
            spi_sck_o        => spi_sck_o,
            spi_mosi_o       => spi_mosi_o,
            spi_miso_i       => spi_miso_i,
            mcp_int_n_i      => mcp_int_n_i,
            mcp_rx0bf_n_i    => mcp_rx0bf_n_i,
            mcp_rx1bf_n_i    => mcp_rx1bf_n_i,
            mcp_txrts_n_o    => mcp_txrts_n_o,
            mcp_reset_n_o    => mcp_reset_n_o
        );

end architecture rtl;
